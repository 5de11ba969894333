"""Checks for `mamma-kit doctor`: the embedded open body and the optional smplx package."""

from __future__ import annotations

from mamma_kit.core.doctor import check as _check


def checks() -> list[dict]:
    out = []
    try:
        from mamma_kit.body.model import load_body_model

        m = load_body_model("open")
        ok = m.num_joints == 55 and len(m.landmarks) == 512
        out.append(_check("body model (open)", ok, f"{m.name} {m.sha256[:12]}: {m.num_vertices} vertices, "
                                                   f"{m.num_joints} joints, {len(m.landmarks)} landmarks",
                          "reinstall mamma-kit (mamma_kit/body/data/open_body.npz)"))
    except Exception as e:  # noqa: BLE001 - report any failure
        out.append(_check("body model (open)", False, f"{type(e).__name__}: {e}",
                          "reinstall mamma-kit, or re-bake: python -m mamma_kit.body.bake"))
    try:
        import smplx  # noqa: F401

        out.append(_check("smplx package (cross-checks)", True, "importable", optional=True))
    except Exception as e:  # noqa: BLE001
        out.append(_check("smplx package (cross-checks)", False, f"not importable ({type(e).__name__})",
                          "pip install 'mamma-kit[smplx]' (MPI licence; only for cross-checks)", optional=True))
    return out
