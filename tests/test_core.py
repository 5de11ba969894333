"""Core utilities: atomic writes, manifests (freshness by input hashes), clock models, workspace."""

import numpy as np
import pytest

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import atomic_path, read_npz, write_npz
from mamma_kit.core.manifest import StageManifest
from mamma_kit.core.workspace import Workspace


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.npz"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"partial")
            raise RuntimeError("killed")
    assert not target.exists() and list(tmp_path.iterdir()) == []
    write_npz(target, a=np.arange(3))
    assert read_npz(target)["a"].tolist() == [0, 1, 2]


def test_pickled_npz_is_refused(tmp_path):
    p = tmp_path / "evil.npz"
    np.savez(p, obj=np.array([{"a": 1}], dtype=object))
    with pytest.raises(UserError, match="pickled"):
        read_npz(p)


def test_manifest_freshness(tmp_path):
    ws = tmp_path
    inp = ws / "in.txt"
    out = ws / "out.txt"
    inp.write_text("a")
    m = StageManifest(ws / ".cache", "stage", ws)
    assert not m.check([inp], {"k": 1}).fresh
    out.write_text("result")
    m.record([inp], {"k": 1}, [out])
    assert m.check([inp], {"k": 1}).fresh
    assert "settings" in m.check([inp], {"k": 2}).reason
    inp.write_text("b")
    state = m.check([inp], {"k": 1})
    assert not state.fresh and "in.txt" in state.reason
    inp.write_text("a")
    assert m.check([inp], {"k": 1}).fresh
    out.write_text("edited")
    assert "output" in m.check([inp], {"k": 1}).reason


def test_clock_model_roundtrip():
    c = ClockModel(offset=0.1234, rate=16e-6, source="clap", confidence=0.9)
    t = np.array([0.0, 10.0, 300.0])
    assert np.allclose(c.to_cam(c.to_ref(t)), t)
    assert c.to_ref(300.0) == pytest.approx(300 * (1 + 16e-6) + 0.1234)
    back = ClockModel.from_dict(c.to_dict())
    assert back.rate_ppm == pytest.approx(16.0) and back.offset == pytest.approx(0.1234)


def test_workspace_paths_cannot_escape(tmp_path):
    ws = Workspace(tmp_path)
    (tmp_path / "capture.toml").write_text('[cameras.a]\nvideo = "../../etc/passwd"\n')
    with pytest.raises(UserError, match="outside the workspace"):
        ws.load_capture()
    (tmp_path / "capture.toml").write_text('[cameras.a]\nvideo = "videos/a.mp4"\n[settings.sync]\nmethod = "clap"\n')
    cap = ws.load_capture()
    assert cap.cameras["a"].video == tmp_path.resolve() / "videos" / "a.mp4"
    assert cap.stage_settings("sync") == {"method": "clap"}
    with pytest.raises(UserError, match="workspace not found"):
        Workspace(tmp_path / "nope")
