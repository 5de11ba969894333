"""landmarks/smooth.py: the network's flickering contact and visibility, denoised over time and
over neighbouring landmarks, on a track whose truth is known."""

from __future__ import annotations

import numpy as np

from mamma_kit.core.tracks import LandmarkTracks
from mamma_kit.landmarks.smooth import landmark_neighbours, smooth_over_time, smooth_probabilities


def _auc(truth: np.ndarray, score: np.ndarray) -> float:
    """ROC AUC by ranks (Mann-Whitney)."""
    from scipy.stats import rankdata

    r = rankdata(score.ravel())
    pos = truth.ravel().astype(bool)
    n1, n0 = pos.sum(), (~pos).sum()
    return float((r[pos].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def test_flicker_is_smoothed_in_seconds_and_tracks_stay_apart():
    """A contact that holds for a second, seen through per-frame noise: smoothing raises its AUC;
    the same smoothing in seconds at 30 and 60 fps; frames where the track is absent are neither
    changed nor used; another track's values do not leak in."""
    rng = np.random.default_rng(0)
    aucs = {}
    for fps in (30, 60):
        T, K, L = 3 * fps, 2, 40
        t = np.arange(T) / fps
        truth = np.zeros((T, K, L), bool)
        truth[fps:2 * fps, 0, :20] = True  # track 0 touches with 20 landmarks for one second
        p = np.clip(truth * 0.6 + 0.2 + rng.normal(0, 0.4, truth.shape), 0, 1).astype(np.float32)
        valid = np.ones((T, K), bool)
        valid[5:9, 1] = False
        p[5:9, 1] = 7.0  # absent frames hold junk that must not spread
        out = smooth_over_time(p, valid, t, 0.1)
        assert np.array_equal(out[5:9, 1], p[5:9, 1])
        assert out[valid].max() <= 1.0 and out[valid[:, 1], 1].mean() < 0.3  # nothing from track 0 or the junk
        aucs[fps] = (_auc(truth[:, 0], p[:, 0]), _auc(truth[:, 0], out[:, 0]))
    for fps, (before, after) in aucs.items():
        assert after > before + 0.05 and after > 0.95, (fps, before, after)
    assert abs(aucs[30][1] - aucs[60][1]) < 0.03


def test_contact_is_averaged_over_neighbouring_landmarks_and_visibility_over_time():
    """smooth_probabilities on a LandmarkTracks: contact over time and its k nearest landmarks
    (a lone spike among neighbours that do not touch is damped), visibility over time only, the
    positions and floor contact untouched; sigma 0 and k = 1 change nothing."""
    T, K, L = 30, 1, 6
    lt = LandmarkTracks.empty("cam0", (640, 480), np.arange(T) / 30.0, np.array([0]), n_landmarks=L)
    lt.valid[:] = True
    lt.xy[:] = 100.0
    lt.contact[:] = 0.1
    lt.contact[15, 0, 0] = 1.0  # one landmark, one frame
    lt.visibility[:] = 1.0
    lt.visibility[10, 0, :] = 0.0
    lt.floor_contact[:] = 0.3
    points_l3 = np.c_[np.arange(L) * 0.01, np.zeros(L), np.zeros(L)]  # a row: neighbours 1 cm apart
    nn = landmark_neighbours(points_l3, 3)
    assert np.array_equal(nn[:, 0], np.arange(L))
    out = smooth_probabilities(lt, 0.05, nn)
    assert out.contact[15, 0, 0] < 0.5 and out.contact[15, 0, 1] > 0.1  # spread to its neighbour
    assert out.contact[15, 0, 5] == np.float32(0.1)  # not to a far landmark
    assert 0.3 < out.visibility[10, 0, 0] < 1.0 and out.visibility[0, 0, 0] == 1.0
    assert np.array_equal(out.xy, lt.xy) and np.array_equal(out.floor_contact, lt.floor_contact)
    same = smooth_probabilities(lt, 0.0, None)
    assert np.array_equal(same.contact, lt.contact) and np.array_equal(same.visibility, lt.visibility)


def test_rows_smoothed_as_they_stream_equal_the_whole_take_smoothed():
    """The landmarks stage smooths rows as they come (RowSmoother): to the bit what smoothing the
    whole take at once gives, whatever the batches and irregular frame times."""
    from mamma_kit.core.tracks import LandmarkTracks
    from mamma_kit.landmarks.smooth import RowSmoother, landmark_neighbours, smooth_probabilities

    rng = np.random.default_rng(1)
    T, K, L = 120, 5, 32
    times = np.cumsum(rng.uniform(0.03, 0.04, T))
    lt = LandmarkTracks.empty("c", (100, 100), times, np.arange(K), L)
    lt.valid[:] = rng.random((T, K)) < 0.6
    lt.visibility[:] = np.where(lt.valid[..., None], rng.random((T, K, L)), 0)
    lt.contact[:] = np.where(lt.valid[..., None], rng.random((T, K, L)), 0)
    nn = landmark_neighbours(rng.random((L, 3)), 4)
    ref = smooth_probabilities(lt, 0.1, nn)
    sm = RowSmoother(times, 0.1, nn)
    t_n, k_n = np.nonzero(lt.valid)
    out, i = [], 0
    while i < len(t_n):
        s = slice(i, i + int(rng.integers(1, 12)))
        i = s.stop
        out.append(sm.push(t_n[s], k_n[s], {"visibility": lt.visibility[t_n[s], k_n[s]],
                                            "contact": lt.contact[t_n[s], k_n[s]]}, complete_before=t_n[s][-1]))
    out.append(sm.finish())
    assert np.array_equal(np.concatenate([o[0] for o in out]), t_n)
    assert np.array_equal(np.concatenate([o[1] for o in out]), k_n)
    for key in ("visibility", "contact"):
        assert np.array_equal(np.concatenate([o[2][key] for o in out]), getattr(ref, key)[t_n, k_n])
