"""The capture report: one self-contained HTML page of everything a workspace holds.

``build_report(ws)`` writes ``report/index.html`` with every picture embedded (base64 data
URIs; no network, no external scripts or styles) and returns a JSON-able summary. Sections
appear as far as their inputs exist; a missing input is named with the command that makes it:

1. rig and calibration   calibration.toml, report/calibration/*.png, smplx/ (people in the rig)
2. synchronisation       timing.toml, report/sync/*.png
3. tracks and matching   masks/, report/tracks/, identities.json, report/match/affinities.png
4. fit                   smplx/, fit_report.json, reprojection error per camera over time
5. contact               landmarks/: contact probabilities over time and per landmark
6. overlays              the fitted meshes over the videos (PNG stills and a short MP4)
7. ground truth          gt/ (synthetic workspaces): `mamma-kit eval`'s metrics

New figures are written as PNGs under report/ (rig/, fit/, contact/, overlays/, gt/) besides
being embedded. ``rerun=True`` also writes report/recording.rrd (needs rerun-sdk).

Modules: build.py (``build_report`` and the sections), tables.py (their tables and captions),
stage.py (``run_report``, the workspace stage with its manifest, and ``report_inputs``),
data.py (everything read from the workspace), analysis.py (reprojection and contact over time),
figures.py and overlays.py (pictures), html.py (the page), rerun_export.py (the .rrd recording).
"""

__all__ = ["build", "stage"]
