"""Import and export of the calibration formats users bring.

======================  =====================================================================
format                  file(s) and conventions
======================  =====================================================================
``mamma-kit``           calibration.toml (core/calibfile.py): world->camera rvec, t in metres
``mamma-yaml``          official MAMMA YAML: ``cameras: {name: {intrinsics: [fx, fy, cx, cy],
                        distortion_model: radtan|equidistant|vicon_radial_2, distortion_coeffs,
                        resolution, translation, rotation_quaternion [w, x, y, z]}}``; pose
                        camera->world; vicon_radial_2 coefficients [pp_x, pp_y, rad_1, rad_2,
                        rad_3] in pixels (core.camera's ``vicon_radial``)
``easymocap``           intri.yml + extri.yml (OpenCV FileStorage): K_<n>, dist_<n>, R_<n>
                        (rvec), Rot_<n>, T_<n>, plus H_<n>/W_<n>; world->camera
``anipose``             aniposelib TOML: [cam_i] name, size, matrix, distortions, rotation
                        (rvec), translation, fisheye; world->camera
``caliscope``           camera_array.toml: [cameras.<id>] size, matrix, distortions,
                        rotation (3x3 or rvec), translation, rotation_count; world->camera.
                        rotation_count (quarter turns the app applies to the display) does not
                        change the intrinsics, which refer to the stored frames; it is kept in
                        Camera.meta and written back.
``opencv-json``         {"cameras": {name: {image_size, camera_matrix, dist_coeffs,
                        distortion_model, rvec, tvec}}}; world->camera
``qualisys``            read only: QTM's .qca.txt (XML). Per <camera serial=name>: fov_video
                        left/top/right/bottom (inclusive pixel bounds on the sensor),
                        intrinsic focalLengthU/V, centerPointU/V (1/64 px, the centre on the
                        whole sensor, so fov_video left/top are subtracted), radialDistortion1-3
                        and tangentalDistortion1-2 (OpenCV k1-k3, p1, p2), transform r11..r33
                        (camera->world rotation stored by columns) and x, y, z (camera
                        position, mm). Qualisys camera axes are OpenCV's turned by pi about x.
``vicon-xcp``           Vicon .xcp (XML): ``<Cameras><Camera DEVICEID SENSOR_SIZE="w h"
                        PIXEL_ASPECT_RATIO><KeyFrames><KeyFrame FOCAL_LENGTH PRINCIPAL_POINT
                        ORIENTATION="x y z w" POSITION="x y z" VICON_RADIAL2="Vicon3Parameter
                        pp_x pp_y rad_1 rad_2 rad_3"/>``. fy = FOCAL_LENGTH / PIXEL_ASPECT_RATIO;
                        the quaternion (scalar last) is the world->camera rotation and POSITION
                        the camera centre in mm (as the public readers of the format use them:
                        t = -R C). Cameras are named by DEVICEID (USERID if it has none).
======================  =====================================================================

Every converter maps exactly (up to float round-off) what both formats can hold. A lens
model a format cannot hold is refused with a message rather than silently changed, except
Vicon's radial model, which is written to OpenCV formats as the closest radtan lens (fitted
over the image) with a warning that says how far its projections move.
"""

from __future__ import annotations

import json
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import yaml

from mamma_kit.core.calibfile import read_calibration, write_calibration
from mamma_kit.core.camera import Camera, Rig, nearest_rotation, rodrigues, rotvec
from mamma_kit.core.errors import UserError
from mamma_kit.core.lens import LENSES
from mamma_kit.core.io import atomic_path, atomic_write_text, to_json, write_toml

# formats read and written (every pair round-trips); READ_FORMATS adds those only read
FORMATS = ("mamma-kit", "mamma-yaml", "easymocap", "anipose", "caliscope", "opencv-json", "vicon-xcp")
READ_ONLY_FORMATS = ("qualisys",)
READ_FORMATS = FORMATS + READ_ONLY_FORMATS
# lens models each format can hold (names from core/lens.py's LENSES; mamma-kit's own holds all)
SUPPORTED_MODELS = {
    "mamma-kit": set(LENSES),
    "opencv-json": {"radtan", "rational", "fisheye"},
    "anipose": {"radtan", "rational", "fisheye"},
    "easymocap": {"radtan", "rational"},
    "mamma-yaml": {"radtan", "fisheye", "vicon_radial"},
    "caliscope": {"radtan"},
    "vicon-xcp": {"vicon_radial"},
}


# ---- helpers --------------------------------------------------------------------------
def _quat_wxyz_from_R(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def _R_from_quat_wxyz(q) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    w, x, y, z = np.asarray(q, float)
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def _dist5(cam: Camera) -> list[float]:
    d = list(cam.dist)
    if cam.model == "radtan" and len(d) < 5:
        d = d + [0.0] * (5 - len(d))
    return [float(v) for v in d]


def _check_models(rig: Rig, fmt: str) -> None:
    for c in rig:
        if c.model not in SUPPORTED_MODELS[fmt]:
            holders = [f for f in FORMATS if c.model in SUPPORTED_MODELS[f]]
            raise UserError(
                f"the {fmt} format cannot hold the {c.model} lens model of camera {c.name}",
                f"convert to {' or '.join(holders)} instead",
            )


def _lossy(rig: Rig, fmt: str) -> Rig:
    """The rig a format can hold: vicon_radial cameras become their closest radtan lens
    when ``fmt`` cannot hold vicon_radial but holds radtan, with a warning of what moves."""
    from mamma_kit.calibration.lens import radtan_equivalent
    from mamma_kit.core import log

    out = []
    for c in rig:
        if c.model == "vicon_radial" and "vicon_radial" not in SUPPORTED_MODELS[fmt] \
                and "radtan" in SUPPORTED_MODELS[fmt]:
            c2, worst = radtan_equivalent(c)
            log.warn(f"{fmt} cannot hold the vicon_radial lens of camera {c.name}: written as the closest radtan "
                     f"lens (k1, k2, p1, p2, k3 fitted over the image); its projections move by up to {worst:.3f} px "
                     f"(lost: Vicon's distortion centre ({c.dist[0]:.1f}, {c.dist[1]:.1f}) px and its exact radial "
                     f"terms)")
            c = c2
        out.append(c)
    return Rig(out)


def _need(d: dict, key: str, cam: str, path: Path):
    if key not in d:
        raise UserError(f"{path.name}: camera {cam} is missing '{key}'", "fix the file or recalibrate")
    return d[key]


def _num(value, shape, cam: str, key: str, path: Path) -> np.ndarray:
    try:
        a = np.asarray(value, float)
    except (TypeError, ValueError):
        raise UserError(f"{path.name}: camera {cam}: '{key}' is not numeric", "fix the file") from None
    if shape is not None and a.size != int(np.prod(shape)):
        raise UserError(f"{path.name}: camera {cam}: '{key}' has {a.size} numbers, expected {int(np.prod(shape))}",
                        "fix the file")
    return a.reshape(shape) if shape is not None else a.reshape(-1)


def _rotation_any(value, cam: str, key: str, path: Path) -> np.ndarray:
    a = _num(value, None, cam, key, path)
    if a.size == 3:
        return rodrigues(a)
    if a.size == 9:
        return nearest_rotation(a.reshape(3, 3))
    raise UserError(f"{path.name}: camera {cam}: '{key}' must be a rotation vector or 3x3 matrix", "fix the file")


# ---- mamma-yaml (official MAMMA) ------------------------------------------------------
def read_mamma_yaml(path: Path) -> Rig:
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise UserError(f"{path.name} is not valid YAML ({str(e).splitlines()[0]})", "fix the syntax") from None
    cams = (data or {}).get("cameras") if isinstance(data, dict) else None
    if not isinstance(cams, dict) or not cams:
        raise UserError(f"{path.name} has no 'cameras' mapping", "is this a MAMMA calibration YAML?")
    out = []
    for name, d in cams.items():
        fx, fy, cx, cy = _num(_need(d, "intrinsics", name, path), (4,), name, "intrinsics", path)
        dm = str(d.get("distortion_model", "radtan"))
        dist = _num(d.get("distortion_coeffs", []), None, name, "distortion_coeffs", path)
        model = {"radtan": "radtan", "equidistant": "fisheye", "none": "radtan",
                 "vicon_radial_2": "vicon_radial"}.get(dm)
        if model is None:
            raise UserError(f"{path.name}: camera {name}: distortion model '{dm}' is not supported",
                            "use radtan, equidistant or vicon_radial_2")
        if model == "vicon_radial" and len(dist) != 5:
            raise UserError(f"{path.name}: camera {name}: vicon_radial_2 takes 5 coefficients [pp_x, pp_y, rad_1, "
                            f"rad_2, rad_3], got {len(dist)}", "fix distortion_coeffs")
        w, h = _num(_need(d, "resolution", name, path), (2,), name, "resolution", path)
        C = _num(_need(d, "translation", name, path), (3,), name, "translation", path)
        R_wc = _R_from_quat_wxyz(_num(_need(d, "rotation_quaternion", name, path), (4,), name,
                                      "rotation_quaternion", path))
        R = R_wc.T
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        out.append(Camera(str(name), (int(w), int(h)), K, dist, model, R, -R @ C))
    return Rig(out)


def write_mamma_yaml(rig: Rig, path: Path) -> None:
    _check_models(rig, "mamma-yaml")
    cams = {}
    for c in rig:
        if abs(c.K[0, 1]) > 1e-12:
            raise UserError(f"camera {c.name} has a skewed K, which mamma-yaml cannot hold", "use opencv-json")
        cams[c.name] = {
            "camera_model": "pinhole",
            "distortion_model": {"fisheye": "equidistant", "vicon_radial": "vicon_radial_2"}.get(c.model, "radtan"),
            "intrinsics": [float(c.K[0, 0]), float(c.K[1, 1]), float(c.K[0, 2]), float(c.K[1, 2])],
            "distortion_coeffs": [float(v) for v in c.dist] if c.model == "vicon_radial" else _dist5(c),
            "resolution": [int(c.size[0]), int(c.size[1])],
            "translation": [float(v) for v in c.center],
            "rotation_quaternion": [float(v) for v in _quat_wxyz_from_R(c.R.T)],
        }
    atomic_write_text(path, yaml.safe_dump({"cameras": cams}, sort_keys=False))


# ---- EasyMocap ------------------------------------------------------------------------
def _easymocap_paths(path: Path) -> tuple[Path, Path]:
    folder = path if path.is_dir() or path.suffix == "" else path.parent
    return folder / "intri.yml", folder / "extri.yml"


def _fs_names(fs, path: Path) -> list[str]:
    node = fs.getNode("names")
    if node.empty():
        raise UserError(f"{path.name} has no 'names' list", "is this an EasyMocap intri.yml/extri.yml?")
    return [node.at(i).string() for i in range(node.size())]


def read_easymocap(path: Path) -> Rig:
    intri, extri = _easymocap_paths(path)
    for p in (intri, extri):
        if not p.is_file():
            raise UserError(f"EasyMocap calibration needs {p.name} beside it, not found in {p.parent}",
                            "put intri.yml and extri.yml in one folder")
    fi = cv2.FileStorage(str(intri), cv2.FILE_STORAGE_READ)
    fe = cv2.FileStorage(str(extri), cv2.FILE_STORAGE_READ)
    try:
        names = _fs_names(fi, intri)
        out = []
        for n in names:
            K = fi.getNode(f"K_{n}").mat()
            dist = fi.getNode(f"dist_{n}").mat()
            if K is None:
                raise UserError(f"{intri.name}: camera {n} is missing 'K_{n}'", "fix the file")
            dist = np.zeros(5) if dist is None else dist.reshape(-1)
            Rn = fe.getNode(f"Rot_{n}").mat()
            if Rn is None:
                rv = fe.getNode(f"R_{n}").mat()
                if rv is None:
                    raise UserError(f"{extri.name}: camera {n} is missing 'R_{n}'", "fix the file")
                Rn = rodrigues(rv.reshape(3))
            T = fe.getNode(f"T_{n}").mat()
            if T is None:
                raise UserError(f"{extri.name}: camera {n} is missing 'T_{n}'", "fix the file")
            H = fi.getNode(f"H_{n}").real()
            W = fi.getNode(f"W_{n}").real()
            size = (int(W), int(H)) if W and H else (int(round(2 * K[0, 2] + 1)), int(round(2 * K[1, 2] + 1)))
            model = "rational" if len(dist) in LENSES["rational"].n_coeffs else "radtan"
            out.append(Camera(n, size, K, dist, model, nearest_rotation(Rn), T.reshape(3),
                              meta={} if (W and H) else {"size_guessed": True}))
        return Rig(out)
    finally:
        fi.release()
        fe.release()


def write_easymocap(rig: Rig, path: Path) -> None:
    _check_models(rig, "easymocap")
    intri, extri = _easymocap_paths(path)
    intri.parent.mkdir(parents=True, exist_ok=True)
    for target, writer in ((intri, _write_intri), (extri, _write_extri)):
        with atomic_path(target, ".yml") as tmp:
            fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
            fs.startWriteStruct("names", cv2.FileNode_SEQ)
            for c in rig:
                fs.write("", c.name)
            fs.endWriteStruct()
            writer(fs, rig)
            fs.release()


def _write_intri(fs, rig: Rig) -> None:
    for c in rig:
        fs.write(f"K_{c.name}", c.K)
        fs.write(f"dist_{c.name}", np.asarray(_dist5(c), float).reshape(1, -1))
        fs.write(f"H_{c.name}", int(c.size[1]))
        fs.write(f"W_{c.name}", int(c.size[0]))


def _write_extri(fs, rig: Rig) -> None:
    for c in rig:
        fs.write(f"R_{c.name}", c.rvec.reshape(3, 1))
        fs.write(f"Rot_{c.name}", c.R)
        fs.write(f"T_{c.name}", c.t.reshape(3, 1))


# ---- anipose / aniposelib -------------------------------------------------------------
def read_anipose(path: Path) -> Rig:
    data = _read_toml_any(path)
    keys = [k for k, v in data.items() if k != "metadata" and isinstance(v, dict)]
    if not keys:
        raise UserError(f"{path.name} has no [cam_*] tables", "is this an anipose calibration?")
    out = []
    for k in keys:
        d = data[k]
        name = str(d.get("name", k))
        K = _num(_need(d, "matrix", name, path), (3, 3), name, "matrix", path)
        dist = _num(d.get("distortions", [0] * 5), None, name, "distortions", path)
        fisheye = bool(d.get("fisheye", False))
        model = "fisheye" if fisheye else ("rational" if len(dist) in LENSES["rational"].n_coeffs else "radtan")
        R = rodrigues(_num(_need(d, "rotation", name, path), (3,), name, "rotation", path))
        t = _num(_need(d, "translation", name, path), (3,), name, "translation", path)
        w, h = _num(_need(d, "size", name, path), (2,), name, "size", path)
        out.append(Camera(name, (int(w), int(h)), K, dist, model, R, t))
    return Rig(out)


def write_anipose(rig: Rig, path: Path, error: float | None = None) -> None:
    _check_models(rig, "anipose")
    data = {}
    for i, c in enumerate(rig):
        data[f"cam_{i}"] = {
            "name": c.name, "size": [int(c.size[0]), int(c.size[1])], "matrix": c.K.tolist(),
            "distortions": _dist5(c), "rotation": c.rvec.tolist(), "translation": c.t.tolist(),
            **({"fisheye": True} if c.model == "fisheye" else {}),
        }
    data["metadata"] = {"adjusted": False, "error": float(error if error is not None else 0.0)}
    write_toml(path, data)


# ---- Caliscope ------------------------------------------------------------------------
def read_caliscope(path: Path) -> Rig:
    data = _read_toml_any(path)
    cams = data.get("cameras")
    if not isinstance(cams, dict):  # older files: [cam_0] tables at the top level
        cams = {k: v for k, v in data.items() if isinstance(v, dict) and "matrix" in v}
    if not cams:
        raise UserError(f"{path.name} has no cameras", "is this a Caliscope camera_array.toml?")
    out = []
    for key, d in cams.items():
        cid = d.get("cam_id", d.get("port", key))
        name = f"cam_{cid}"
        if d.get("ignore", False):
            continue
        if "rotation" not in d or "translation" not in d:
            raise UserError(f"{path.name}: camera {cid} has no extrinsics (not yet calibrated in Caliscope)",
                            "finish the extrinsic calibration in Caliscope first")
        K = _num(_need(d, "matrix", name, path), (3, 3), name, "matrix", path)
        dist = _num(d.get("distortions", [0] * 5), None, name, "distortions", path)
        R = _rotation_any(d["rotation"], name, "rotation", path)
        t = _num(d["translation"], (3,), name, "translation", path)
        w, h = _num(_need(d, "size", name, path), (2,), name, "size", path)
        out.append(Camera(name, (int(w), int(h)), K, dist, "radtan", R, t,
                          meta={"rotation_count": int(d.get("rotation_count", 0)), "cam_id": int(cid)}))
    return Rig(out)


def write_caliscope(rig: Rig, path: Path) -> None:
    _check_models(rig, "caliscope")
    cams = {}
    for i, c in enumerate(rig):
        cid = int(c.meta.get("cam_id", i))
        cams[str(cid)] = {
            "cam_id": cid, "size": [int(c.size[0]), int(c.size[1])],
            "rotation_count": int(c.meta.get("rotation_count", 0)),
            "error": float(c.meta.get("rms_px", 0.0)), "grid_count": 0, "ignore": False,
            "matrix": c.K.tolist(), "distortions": _dist5(c),
            "translation": c.t.tolist(), "rotation": c.R.tolist(),
        }
    write_toml(path, {"cameras": cams})


# ---- plain OpenCV JSON ------------------------------------------------------------------
def read_opencv_json(path: Path) -> Rig:
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise UserError(f"{path.name} is not valid JSON ({e})", "fix the syntax") from None
    cams = data.get("cameras") if isinstance(data, dict) else None
    if not isinstance(cams, dict) or not cams:
        raise UserError(f"{path.name} has no 'cameras' object", "expected {\"cameras\": {name: {...}}}")
    out = []
    for name, d in cams.items():
        K = _num(_need(d, "camera_matrix", name, path), (3, 3), name, "camera_matrix", path)
        dist = _num(d.get("dist_coeffs", []), None, name, "dist_coeffs", path)
        R = _rotation_any(_need(d, "rvec", name, path), name, "rvec", path)
        t = _num(_need(d, "tvec", name, path), (3,), name, "tvec", path)
        w, h = _num(_need(d, "image_size", name, path), (2,), name, "image_size", path)
        out.append(Camera(name, (int(w), int(h)), K, dist, str(d.get("distortion_model", "radtan")), R, t))
    return Rig(out)


def write_opencv_json(rig: Rig, path: Path) -> None:
    _check_models(rig, "opencv-json")
    cams = {c.name: {"image_size": [int(c.size[0]), int(c.size[1])], "camera_matrix": c.K.tolist(),
                     "distortion_model": c.model, "dist_coeffs": c.dist.tolist(),
                     "rvec": c.rvec.tolist(), "tvec": c.t.tolist()} for c in rig}
    atomic_write_text(path, to_json({"cameras": cams}) + "\n")


# ---- Qualisys QTM (.qca.txt), read only --------------------------------------------------
QCA_UNIT = 64.0  # focal lengths and centre point are stored in 1/64 pixel
# the Qualisys camera frame is OpenCV's turned by pi about x (y up, looking along -z)
_QCA_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


def _qca_values(cam_el, tag: str, keys: tuple[str, ...], cam: str, path: Path,
                optional: tuple[str, ...] = ()) -> dict[str, float]:
    el = cam_el.find(tag)
    if el is None:
        raise UserError(f"{path.name}: camera {cam} has no <{tag}> element", "fix the file or export it from QTM again")
    out = {}
    for k in keys:
        v = el.get(k)
        if v is None:
            if k in optional:
                out[k] = 0.0
                continue
            raise UserError(f"{path.name}: camera {cam}: <{tag}> is missing '{k}'",
                            "fix the file or export it from QTM again")
        try:
            out[k] = float(v)
        except ValueError:
            out[k] = float("nan")
        if not np.isfinite(out[k]):
            raise UserError(f"{path.name}: camera {cam}: <{tag}> '{k}' is not a number ({v!r})", "fix the file")
    return out


def _xml_root(path: Path, what: str) -> ET.Element:
    """The root element of an XML calibration file; a UserError naming ``what`` it should be."""
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as e:
        raise UserError(f"{path.name} is not valid XML ({e})", f"is this a {what} calibration?") from None


def read_qualisys(path: Path) -> Rig:
    root = _xml_root(path, "Qualisys .qca.txt")
    cams = root.findall("./cameras/camera") if root.tag == "calibration" else []
    if not cams:
        raise UserError(f"{path.name} has no <calibration><cameras><camera> elements",
                        "is this a Qualisys .qca.txt calibration?")
    out = []
    for i, el in enumerate(cams):
        name = el.get("serial")
        if not name:
            raise UserError(f"{path.name}: camera {i + 1} has no 'serial' (its name)", "fix the file")
        fov = _qca_values(el, "fov_video", ("left", "top", "right", "bottom"), name, path)
        w, h = int(fov["right"] - fov["left"]) + 1, int(fov["bottom"] - fov["top"]) + 1
        if w <= 1 or h <= 1:
            raise UserError(f"{path.name}: camera {name}: <fov_video> gives a {w}x{h} image", "fix the file")
        f = _qca_values(el, "intrinsic", ("focalLengthU", "focalLengthV", "centerPointU", "centerPointV", "skew",
                                          "radialDistortion1", "radialDistortion2", "radialDistortion3",
                                          "tangentalDistortion1", "tangentalDistortion2"),
                        name, path, optional=("skew", "radialDistortion3"))
        fx, fy = f["focalLengthU"] / QCA_UNIT, f["focalLengthV"] / QCA_UNIT
        cx, cy = f["centerPointU"] / QCA_UNIT - fov["left"], f["centerPointV"] / QCA_UNIT - fov["top"]
        if fx <= 0 or fy <= 0 or not (0 <= cx < w and 0 <= cy < h):
            raise UserError(f"{path.name}: camera {name}: focal length ({fx:.1f}, {fy:.1f}) px or principal point "
                            f"({cx:.1f}, {cy:.1f}) px does not fit its {w}x{h} image",
                            "is this a Qualisys .qca.txt calibration (intrinsics in 1/64 pixel)?")
        K = np.array([[fx, f["skew"] / QCA_UNIT, cx], [0, fy, cy], [0, 0, 1.0]])
        dist = [f["radialDistortion1"], f["radialDistortion2"], f["tangentalDistortion1"],
                f["tangentalDistortion2"], f["radialDistortion3"]]
        tr = _qca_values(el, "transform", tuple(f"r{a}{b}" for a in "123" for b in "123") + ("x", "y", "z"),
                         name, path)
        # stored by columns: (r11, r12, r13) is the first column of the camera->world rotation
        R_cam_world = np.array([[tr[f"r{b}{a}"] for b in "123"] for a in "123"])
        if (abs(np.linalg.det(R_cam_world) - 1) > 1e-3
                or np.abs(R_cam_world @ R_cam_world.T - np.eye(3)).max() > 1e-3):
            raise UserError(f"{path.name}: camera {name}: <transform> r11..r33 is not a rotation", "fix the file")
        R = _QCA_TO_OPENCV @ nearest_rotation(R_cam_world).T
        C = np.array([tr["x"], tr["y"], tr["z"]]) / 1000.0
        # QTM's display rotation of the camera's image; the intrinsics refer to the stored frames
        view = el.get("viewrotation", "0").strip()
        meta = {} if view in ("", "0") else {"qualisys_viewrotation": view}
        out.append(Camera(name, (w, h), K, dist, "radtan", R, -R @ C, meta=meta))
    return Rig(out)


# ---- Vicon .xcp ------------------------------------------------------------------------
XCP_MODEL_NAME = "Vicon3Parameter"


def _xcp_numbers(el, key: str, n: int | None, cam: str, path: Path) -> np.ndarray:
    v = el.get(key)
    if v is None:
        raise UserError(f"{path.name}: camera {cam} has no {key}", "fix the file or export it from Vicon again")
    toks = v.split()
    while toks and not _is_number(toks[0]):  # VICON_RADIAL2 starts with its model's name
        toks = toks[1:]
    try:
        a = np.array([float(t) for t in toks])
    except ValueError:
        raise UserError(f"{path.name}: camera {cam}: {key} is not numeric ({v!r})", "fix the file") from None
    if (n is not None and len(a) != n) or not np.all(np.isfinite(a)):
        raise UserError(f"{path.name}: camera {cam}: {key} holds {len(a)} numbers ({v!r}), expected {n}",
                        "fix the file")
    return a


def _is_number(tok: str) -> bool:
    try:
        float(tok)
        return True
    except ValueError:
        return False


def read_xcp(path: Path) -> Rig:
    root = _xml_root(path, "Vicon .xcp")
    cams = root.findall("Camera") if root.tag == "Cameras" else root.findall(".//Cameras/Camera")
    if not cams:
        raise UserError(f"{path.name} has no <Cameras><Camera> elements", "is this a Vicon .xcp calibration?")
    out = []
    for i, el in enumerate(cams):
        name = el.get("DEVICEID") or el.get("USERID") or f"cam{i}"
        kf = el.find("KeyFrames/KeyFrame")
        if kf is None:
            raise UserError(f"{path.name}: camera {name} has no <KeyFrames><KeyFrame> (not calibrated)",
                            "calibrate the cameras in Vicon and export the .xcp again")
        w, h = _xcp_numbers(el, "SENSOR_SIZE", 2, name, path)
        aspect = float(el.get("PIXEL_ASPECT_RATIO", "1") or 1)
        f = _xcp_numbers(kf, "FOCAL_LENGTH", 1, name, path)[0]
        cx, cy = _xcp_numbers(kf, "PRINCIPAL_POINT", 2, name, path)
        q = _xcp_numbers(kf, "ORIENTATION", 4, name, path)
        C = _xcp_numbers(kf, "POSITION", 3, name, path) / 1000.0
        if kf.get("VICON_RADIAL2") is None:
            raise UserError(f"{path.name}: camera {name} has no VICON_RADIAL2 lens (an older VICON_RADIAL model?)",
                            "export the calibration from a Vicon version that writes VICON_RADIAL2")
        dist = _xcp_numbers(kf, "VICON_RADIAL2", 5, name, path)
        if f <= 0 or aspect <= 0 or np.linalg.norm(q) < 1e-9:
            raise UserError(f"{path.name}: camera {name}: focal length {f}, aspect {aspect} or orientation {q} "
                            "is not valid", "fix the file")
        from scipy.spatial.transform import Rotation

        R = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()  # scalar last: x y z w
        K = np.array([[f, 0, cx], [0, f / aspect, cy], [0, 0, 1.0]])
        meta = {k: el.get(k) for k in ("USERID", "DISPLAY_TYPE", "TYPE") if el.get(k)}
        out.append(Camera(str(name), (int(w), int(h)), K, dist, "vicon_radial", R, -R @ C, meta=meta))
    return Rig(out)


def write_xcp(rig: Rig, path: Path) -> None:
    from scipy.spatial.transform import Rotation

    _check_models(rig, "vicon-xcp")
    root = ET.Element("Cameras", {"VERSION": "1.0", "NUM_CAMERAS": str(len(rig))})
    for k, c in enumerate(rig):
        fx, fy = float(c.K[0, 0]), float(c.K[1, 1])
        if abs(c.K[0, 1]) > 1e-12:
            raise UserError(f"camera {c.name} has a skewed K, which .xcp cannot hold", "use mamma-kit's format")
        el = ET.SubElement(root, "Camera", {"DEVICEID": c.name, "USERID": str(c.meta.get("USERID", k + 1)),
                                            "SENSOR_SIZE": f"{c.size[0]} {c.size[1]}",
                                            "PIXEL_ASPECT_RATIO": repr(float(fx / fy)), "TYPE": "VIDEO"})
        kfs = ET.SubElement(el, "KeyFrames")
        q = Rotation.from_matrix(c.R).as_quat()
        ET.SubElement(kfs, "KeyFrame", {
            "FRAME": "0", "FOCAL_LENGTH": repr(fx), "PRINCIPAL_POINT": f"{float(c.K[0, 2])!r} {float(c.K[1, 2])!r}",
            "ORIENTATION": " ".join(repr(float(v)) for v in q),
            "POSITION": " ".join(repr(float(v)) for v in c.center * 1000.0),
            "VICON_RADIAL2": " ".join([XCP_MODEL_NAME] + [repr(float(v)) for v in c.dist]),
            "WORLD_ERROR": "0"})
    ET.indent(root)
    atomic_write_text(path, '<?xml version="1.0" encoding="UTF-8" standalone="no" ?>\n'
                      + ET.tostring(root, encoding="unicode") + "\n")


# ---- dispatch -------------------------------------------------------------------------
def _read_toml_any(path: Path) -> dict:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{path.name} is not valid TOML ({e})", "fix the syntax") from None


def infer_format(path: str | Path, for_writing: bool = False) -> str:
    """Guess a calibration format from the file name, and from its content when reading."""
    p = Path(path)
    name = p.name.lower()
    if name.endswith((".qca.txt", ".qca")):
        return "qualisys"
    if name.endswith(".xcp"):
        return "vicon-xcp"
    if name in ("intri.yml", "extri.yml") or (p.is_dir() and (p / "intri.yml").exists()):
        return "easymocap"
    if name == "camera_array.toml":
        return "caliscope"
    if p.suffix.lower() == ".json":
        return "opencv-json"
    if p.suffix.lower() in (".yml", ".yaml"):
        if not for_writing and p.is_file() and p.read_text(errors="ignore").lstrip().startswith("%YAML:1.0"):
            return "easymocap"
        return "mamma-yaml"
    if p.suffix.lower() == ".toml" and not for_writing and p.is_file():
        data = _read_toml_any(p)
        if data.get("format") == "mamma-kit-calibration":
            return "mamma-kit"
        cams = data.get("cameras")
        if isinstance(cams, dict) and cams and all(isinstance(v, dict) for v in cams.values()):
            first = next(iter(cams.values()))
            if "K" in first:
                return "mamma-kit"
            if "matrix" in first:
                return "caliscope"
        if any(k.startswith("cam_") and isinstance(v, dict) and "matrix" in v for k, v in data.items()):
            return "anipose"
    if p.suffix.lower() == ".toml" and for_writing and name == "calibration.toml":
        return "mamma-kit"
    raise UserError(f"cannot tell the calibration format of {p.name}",
                    f"pass it with --from/--to (one of {', '.join(FORMATS if for_writing else READ_FORMATS)})")


READERS: dict[str, Callable[[Path], Rig]] = {
    "mamma-kit": lambda p: read_calibration(p)[0],
    "mamma-yaml": read_mamma_yaml,
    "easymocap": read_easymocap,
    "anipose": read_anipose,
    "caliscope": read_caliscope,
    "opencv-json": read_opencv_json,
    "qualisys": read_qualisys,
    "vicon-xcp": read_xcp,
}
WRITERS: dict[str, Callable[[Rig, Path], None]] = {
    "mamma-kit": lambda r, p: write_calibration(p, r),
    "mamma-yaml": write_mamma_yaml,
    "easymocap": write_easymocap,
    "anipose": write_anipose,
    "caliscope": write_caliscope,
    "opencv-json": write_opencv_json,
    "vicon-xcp": write_xcp,
}


def _check_fmt(fmt: str, for_writing: bool = False) -> str:
    if for_writing and fmt in READ_ONLY_FORMATS:
        raise UserError(f"the {fmt} calibration format is read-only", f"write one of {', '.join(FORMATS)}")
    if fmt not in READ_FORMATS:
        raise UserError(f"unknown calibration format '{fmt}'", f"use one of {', '.join(READ_FORMATS)}")
    return fmt


def read_rig(path: str | Path, fmt: str | None = None) -> Rig:
    p = Path(path)
    fmt = _check_fmt(fmt or infer_format(p))
    if fmt != "easymocap" and not p.is_file():
        raise UserError(f"calibration file not found: {p}", "check the path")
    if fmt == "easymocap" and not (p.exists() or p.parent.exists()):
        raise UserError(f"calibration not found: {p}", "check the path")
    return READERS[fmt](p)


def write_rig(rig: Rig, path: str | Path, fmt: str | None = None) -> Path:
    p = Path(path)
    fmt = _check_fmt(fmt or infer_format(p, for_writing=True), for_writing=True)
    WRITERS[fmt](_lossy(rig, fmt), p)
    return p


def convert(src: str | Path, dst: str | Path, src_fmt: str | None = None, dst_fmt: str | None = None,
            names: list[str] | None = None, scale: float = 1.0) -> tuple[Rig, str, str]:
    """Read ``src`` and write ``dst``; optionally rename cameras (in order) and scale
    translations (e.g. 0.001 for a file in millimetres)."""
    src_fmt = _check_fmt(src_fmt or infer_format(src))
    dst_fmt = _check_fmt(dst_fmt or infer_format(dst, for_writing=True), for_writing=True)
    rig = read_rig(src, src_fmt)
    if names:
        if len(names) != len(rig):
            raise UserError(f"--names lists {len(names)} names but {Path(src).name} holds {len(rig)} cameras",
                            "give one name per camera, in file order")
        rig = Rig([c.copy(name=n) for c, n in zip(rig, names)])
    if scale != 1.0:
        rig = Rig([c.copy(t=c.t * scale) for c in rig])
    write_rig(rig, dst, dst_fmt)
    return rig, src_fmt, dst_fmt


def rig_projection_difference(a: Rig, b: Rig, points_n3: np.ndarray) -> float:
    """Max pixel difference between two rigs (matched by order) over the points that
    project inside each image of ``a`` (outside it a lens model means nothing)."""
    worst = 0.0
    for ca, cb in zip(a, b):
        pa, pb = ca.project(points_n3), cb.project(points_n3)
        ok = np.isfinite(pa).all(-1) & (pa >= -0.5).all(-1) & (pa < np.array(ca.size) - 0.5).all(-1)
        if ok.any():
            worst = max(worst, float(np.abs(pa[ok] - pb[ok]).max()))
    return worst


__all__ = ["FORMATS", "READ_FORMATS", "convert", "read_rig", "write_rig", "infer_format", "rig_projection_difference",
           "rotvec"]
