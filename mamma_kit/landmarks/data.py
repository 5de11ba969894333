"""Training crops on disk: shards written by `mamma-kit synth RECIPE --crops N --out DIR`.

Format (one folder)::

    DIR/meta.json            landmark_set (str), recipes, seeds, counts; optional
                             landmark_parts (L ints) + landmark_part_names (names) for the
                             hand/foot loss weights
    DIR/shard_NNNN.npz       images        (N, H, W, 3) uint8  crop with generous context (x1.6 box)
                             instance      (N, H, W) uint8     0 background, 1 target, 2.. others
                             xy            (N, L, 2) float32   crop px, pixel-centre convention
                             visibility    (N, L) uint8
                             contact       (N, L) uint8
                             floor_contact (N, L) uint8
                             box           (N, 4) float32      target's tight box x1, y1, x2 + 1, y2 + 1 (crop px;
                                                               training boxes the instance map itself as
                                                               inference boxes the mask; box is the fallback)
                             [landmark_part (L,) int, optional, same meaning as in meta.json]
    DIR/keypoints_NNNN.npz   keypoints     (N, 33, 5) float32  the keypoint model's points of the target in
                             model         str                 the crop (x, y crop px, z, visibility, presence;
                                                               NaN where it found no pose), written by
                                                               ``annotate_keypoints`` for keypoint-guided models

:class:`CropShards` reads one or more such folders lazily (a few decompressed shards cached) and
gives a deterministic sample order per (seed, epoch) that visits shards one after another, so
training reads each shard once per epoch and resuming at step s replays the same batches.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_npz, write_json, write_npz

SHARD_KEYS = ("images", "instance", "xy", "visibility", "contact", "floor_contact", "box")


@dataclass
class _Shard:
    path: Path
    n: int


class CropShards:
    """Crops from shard folders. ``shards[i]`` -> dict of one sample's arrays."""

    def __init__(self, dirs: list[str | Path] | str | Path, cache_shards: int = 2):
        dirs = [dirs] if isinstance(dirs, (str, Path)) else list(dirs)
        if not dirs:
            raise UserError("no crop shard folders given", "list shard folders in the training config's [data]")
        self.dirs = [Path(d) for d in dirs]
        self.meta: list[dict] = []
        self.shards: list[_Shard] = []
        for d in self.dirs:
            if not d.is_dir():
                raise UserError(f"crop shard folder not found: {d}",
                                "write crops with `mamma-kit synth RECIPE --crops N --out DIR`")
            files = sorted(d.glob("shard_*.npz"))
            if not files:
                raise UserError(f"{d} holds no shard_*.npz files", "write crops with `mamma-kit synth --crops`")
            meta_path = d / "meta.json"
            meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
            self.meta.append(meta)
            for f in files:
                self.shards.append(_Shard(f, _shard_len(f)))
        sets = {m.get("landmark_set", "") for m in self.meta}
        if len(sets) > 1:
            raise UserError(f"shard folders mix landmark sets {sorted(sets)}", "train on crops of one landmark set")
        self.landmark_set = sets.pop() if sets else ""
        self.counts = np.array([s.n for s in self.shards], np.int64)
        self.starts = np.r_[0, np.cumsum(self.counts)[:-1]]
        self._cache: OrderedDict[int, dict] = OrderedDict()
        self._cache_size = max(1, cache_shards)
        self._orders: dict[tuple[int, int], np.ndarray] = {}
        first = self.shard_arrays(0)
        self.n_landmarks = int(first["xy"].shape[1])
        self.crop_hw = tuple(int(v) for v in first["images"].shape[1:3])
        self.landmark_parts, self.part_names = self._parts(first)

    def _parts(self, first: dict) -> tuple[np.ndarray | None, list[str]]:
        m = self.meta[0]
        names = list(m.get("landmark_part_names", []))
        part = first.get("landmark_part")
        if part is None and "landmark_parts" in m:
            part = np.asarray(m["landmark_parts"], np.int64)
        if part is not None and len(part) != self.n_landmarks:
            raise UserError(f"landmark_parts has {len(part)} entries, shards hold {self.n_landmarks} landmarks",
                            "regenerate the crop shards")
        return (None if part is None else np.asarray(part, np.int64)), names

    def __len__(self) -> int:
        return int(self.counts.sum())

    def describe(self) -> dict:
        return {"dirs": [str(d) for d in self.dirs], "samples": len(self), "shards": len(self.shards),
                "landmark_set": self.landmark_set, "n_landmarks": self.n_landmarks, "crop_hw": list(self.crop_hw),
                "recipes": sorted({str(r) for m in self.meta for r in _as_list(m.get("recipes", m.get("recipe")))}),
                "seeds": sorted({str(s) for m in self.meta for s in _as_list(m.get("seeds", m.get("seed")))})}

    # ---- access ---------------------------------------------------------------------------
    @property
    def has_keypoints(self) -> bool:
        """Every shard has its keypoints file (``annotate_keypoints``)."""
        return all(keypoints_path(s.path).is_file() for s in self.shards)

    def shard_arrays(self, j: int) -> dict[str, np.ndarray]:
        if j in self._cache:
            self._cache.move_to_end(j)
            return self._cache[j]
        d = read_npz(self.shards[j].path, "crop shard")
        missing = [k for k in SHARD_KEYS if k not in d]
        if missing:
            raise UserError(f"crop shard {self.shards[j].path} is missing {', '.join(missing)}",
                            "regenerate it with `mamma-kit synth --crops`")
        kp = keypoints_path(self.shards[j].path)
        if kp.is_file():
            d["keypoints"] = read_npz(kp, "crop keypoints")["keypoints"]
        self._cache[j] = d
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return d

    def locate(self, i: int) -> tuple[int, int]:
        j = int(np.searchsorted(self.starts, i, side="right") - 1)
        return j, int(i - self.starts[j])

    def __getitem__(self, i: int) -> dict[str, np.ndarray]:
        j, k = self.locate(int(i))
        d = self.shard_arrays(j)
        out = {key: d[key][k] for key in SHARD_KEYS + (("keypoints",) if "keypoints" in d else ())}
        out["index"] = np.int64(i)
        return out

    # ---- deterministic order --------------------------------------------------------------
    def epoch_order(self, seed: int, epoch: int) -> np.ndarray:
        """A permutation of all samples: shards in a random order, samples shuffled within each."""
        key = (seed, epoch)
        if key not in self._orders:
            rng = np.random.default_rng([seed, epoch])
            parts = [self.starts[j] + np.random.default_rng([seed, epoch, int(j)]).permutation(self.counts[j])
                     for j in rng.permutation(len(self.shards))]
            self._orders = {key: np.concatenate(parts)}  # keep only the current epoch
        return self._orders[key]

    def batch_indices(self, seed: int, step: int, batch: int) -> np.ndarray:
        """Sample indices of training step ``step`` (a pure function of seed and step)."""
        n = len(self)
        pos = np.arange(step * batch, (step + 1) * batch, dtype=np.int64)
        out = np.empty(batch, np.int64)
        for e in np.unique(pos // n):  # one or two epochs per batch
            sel = pos // n == e
            out[sel] = self.epoch_order(seed, int(e))[pos[sel] % n]
        return out


def keypoints_path(shard: Path) -> Path:
    return shard.with_name(shard.name.replace("shard_", "keypoints_"))


def annotate_keypoints(dirs: list[str | Path] | str | Path, force: bool = False, threads: int | None = None) -> dict:
    """Run the keypoint model on every crop of the shard folders, as the keypoints stage runs it on
    a frame (the target's mask blanks the rest): DIR/keypoints_NNNN.npz beside each shard, so the
    network learns from the detector's real errors. Shards already annotated are skipped."""
    import time

    from mamma_kit.core import log
    from mamma_kit.keypoints.estimator import PoseEstimator
    from mamma_kit.keypoints.stage import MODEL_NAME

    dirs = [dirs] if isinstance(dirs, (str, Path)) else list(dirs)
    shards = [f for d in dirs for f in sorted(Path(d).glob("shard_*.npz"))]
    todo = [f for f in shards if force or not keypoints_path(f).is_file()]
    if not todo:
        return {"crops": 0, "with_pose": 0, "shards": 0, "skipped": len(shards), "seconds": 0.0}
    log.info(f"running the keypoint model on {len(todo)} crop shards (once; kept beside them)")
    est = PoseEstimator(threads)
    n = found = 0
    t0 = time.perf_counter()
    with log.progress("crop keypoints", sum(_shard_len(f) for f in todo)) as advance:
        for f in todo:
            d = read_npz(f, "crop shard")
            kp = np.full((len(d["images"]), 33, 5), np.nan, np.float32)
            for i, (img, inst) in enumerate(zip(d["images"], d["instance"])):
                mask = inst == 1
                ys, xs = np.nonzero(mask)
                if len(xs):
                    kp[i] = est.person_points(img, np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1.0]), mask)
                advance(1)
            write_npz(keypoints_path(f), keypoints=kp, model=np.array(MODEL_NAME))
            n += len(kp)
            found += int(np.isfinite(kp[:, 0, 0]).sum())
    secs = time.perf_counter() - t0
    log.info(f"keypoints for {n} crops ({found} with a pose) in {secs:.0f} s")
    return {"crops": n, "with_pose": found, "shards": len(todo), "skipped": len(shards) - len(todo),
            "seconds": round(secs, 1)}


def _as_list(v) -> list:
    if v is None:
        return []
    return list(v) if isinstance(v, (list, tuple)) else [v]


def _shard_len(path: Path) -> int:
    """Number of samples in a shard, from the .npy header of its 'box' array (no decompression)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z, z.open("box.npy") as f:
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape = read(f)[0]
            return int(shape[0])
    except (KeyError, zipfile.BadZipFile, ValueError, OSError) as e:
        raise UserError(f"crop shard {path} is not a readable shard ({e})", "regenerate it") from None


def write_crop_shards(out_dir: str | Path, samples: dict[str, np.ndarray], meta: dict, shard_size: int = 256,
                      first_index: int = 0) -> list[Path]:
    """Write arrays in the shard format (keys SHARD_KEYS, first axis = sample) plus meta.json."""
    out_dir = Path(out_dir)
    n = len(samples["images"])
    paths = []
    for s, a in enumerate(range(0, n, shard_size)):
        arrays = {k: np.asarray(samples[k][a:a + shard_size]) for k in SHARD_KEYS}
        if "landmark_part" in samples:
            arrays["landmark_part"] = np.asarray(samples["landmark_part"])
        paths.append(write_npz(out_dir / f"shard_{first_index + s:04d}.npz", **arrays))
    write_json(out_dir / "meta.json", {**meta, "counts": {"samples": n, "shards": len(paths)}})
    return paths
