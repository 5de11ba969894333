"""The report's interactive 3D view: the capture's glTF (export/gltf.py: animated bodies, cameras,
floor) played by three.js inside the page, offline: play, pause, scrub, orbit, and the view from
any calibrated camera.

three.js comes from the npm registry (package.json beside pyproject.toml; `make env` runs
`npm ci`), or from the folder MAMMA_KIT_THREE names. Its ES modules are embedded as data: URLs
under an import map; their relative imports are rewritten to the map's names (``three/...``), so
the page needs no server and no network. Without three.js the section says how to install it.

After loading, the page renders the take's first frame and its middle and writes how many pixels
differ into ``data-frames-differ`` of the player (``#view3d-player``, then ``data-view3d="ready"``):
what the headless-browser test reads.
"""

from __future__ import annotations

import base64
import json
import os
import re
from functools import lru_cache
from pathlib import Path

THREE_ENV = "MAMMA_KIT_THREE"
ENTRIES = {"three": "build/three.module.js",
           "three/gltf-loader": "examples/jsm/loaders/GLTFLoader.js",
           "three/orbit-controls": "examples/jsm/controls/OrbitControls.js"}
MAX_FRAMES = 900  # per person: longer takes are strided, as the rerun recording is
_IMPORT = re.compile(r"""((?:\bfrom|\bimport)\s*)(['"])([^'"]+)\2""")


def three_dir() -> Path | None:
    """The installed three.js package folder, or None."""
    env = os.environ.get(THREE_ENV)
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    candidates += [p / "node_modules" / "three" for p in here.parents]
    return next((c for c in candidates if (c / "package.json").is_file() and (c / ENTRIES["three"]).is_file()), None)


@lru_cache(maxsize=2)
def import_map(root: Path) -> dict[str, str]:
    """Specifier -> data: URL of every module the entries need, relative imports rewritten."""
    out: dict[str, str] = {}
    names = {v: k for k, v in ENTRIES.items()}

    def name_of(rel: str) -> str:
        return names.get(rel, "three/" + rel)

    def add(rel: str) -> None:
        if name_of(rel) in out:
            return
        out[name_of(rel)] = ""  # mark before recursing: modules may import each other
        src = (root / rel).read_text(encoding="utf-8")

        def rewrite(m: re.Match) -> str:
            spec = m.group(3)
            if not spec.startswith("."):
                return m.group(0)
            dep = os.path.normpath(os.path.join(os.path.dirname(rel), spec)).replace(os.sep, "/")
            add(dep)
            return f"{m.group(1)}{m.group(2)}{name_of(dep)}{m.group(2)}"

        src = _IMPORT.sub(rewrite, src)
        out[name_of(rel)] = "data:text/javascript;base64," + base64.b64encode(src.encode()).decode("ascii")

    for rel in ENTRIES.values():
        add(rel)
    return out


def _html(glb: bytes, imports: dict[str, str], cameras: list[str], seconds: float) -> str:
    opts = "".join(f'<option value="{c}">camera {c}</option>' for c in cameras)
    return (
        f"<style>{CSS}</style>"
        '<div id="view3d-player" class="view3d" data-view3d="loading">'
        '<div class="view3d-canvas"></div>'
        '<div class="view3d-bar"><button type="button" class="view3d-play">Pause</button>'
        f'<input class="view3d-time" type="range" min="0" max="{seconds:.4f}" step="any" value="0">'
        '<span class="view3d-clock">0.00 s</span>'
        f'<select class="view3d-from"><option value="">free view</option>{opts}</select></div></div>'
        f'<script type="application/octet-stream" id="view3d-glb">{base64.b64encode(glb).decode("ascii")}</script>'
        f'<script type="importmap">{json.dumps({"imports": imports})}</script>'
        f"<script type=\"module\">{VIEWER_JS}</script>"
    )


VIEWER_JS = r"""
import * as THREE from "three";
import { GLTFLoader } from "three/gltf-loader";
import { OrbitControls } from "three/orbit-controls";

const box = document.getElementById("view3d-player");
const W = Math.min(box.clientWidth || 960, 1100), H = Math.round(W * 0.56);
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
renderer.setSize(W, H);
box.querySelector(".view3d-canvas").appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xe9edf1);
scene.add(new THREE.HemisphereLight(0xffffff, 0x7a8088, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(4, 8, 5);
scene.add(sun);
const view = new THREE.PerspectiveCamera(45, W / H, 0.05, 500);
const controls = new OrbitControls(view, renderer.domElement);
const bytes = Uint8Array.from(atob(document.getElementById("view3d-glb").textContent), c => c.charCodeAt(0));

new GLTFLoader().parse(bytes.buffer, "", gltf => {
  const root = gltf.scene;
  root.traverse(o => { if (o.isSkinnedMesh) o.frustumCulled = false; });  // bind-pose bounds would cull a moved body
  scene.add(root);
  root.updateMatrixWorld(true);
  const mixer = new THREE.AnimationMixer(root);
  const clip = gltf.animations[0];
  if (clip) mixer.clipAction(clip).play();
  const duration = clip ? clip.duration : 0;
  const floor = root.getObjectByName("floor");  // 1.5 m beyond where the people walked
  const bounds = new THREE.Box3().setFromObject(floor || root);
  const centre = bounds.getCenter(new THREE.Vector3()); centre.y = 0.9;
  const size = Math.max(bounds.getSize(new THREE.Vector3()).length(), 4);
  function freeView() {
    view.fov = 45; view.updateProjectionMatrix();
    view.position.copy(centre).add(new THREE.Vector3(0.35, 0.5, 0.8).normalize().multiplyScalar(1.0 * size));
    controls.target.copy(centre); controls.update();
  }
  function cameraView(name) {
    const cam = root.getObjectByName("camera/" + name);
    if (!cam) return freeView();
    const glcam = cam.children.find(c => c.isCamera) || cam;
    cam.updateMatrixWorld(true);
    view.position.setFromMatrixPosition(cam.matrixWorld);
    view.quaternion.setFromRotationMatrix(cam.matrixWorld);
    if (glcam.isPerspectiveCamera) view.fov = glcam.fov;
    view.updateProjectionMatrix();
    const ahead = new THREE.Vector3(0, 0, -1).applyQuaternion(view.quaternion);
    controls.target.copy(view.position).addScaledVector(ahead, view.position.distanceTo(centre));
    controls.update();
  }
  freeView();
  const slider = box.querySelector(".view3d-time"), clock = box.querySelector(".view3d-clock");
  const button = box.querySelector(".view3d-play");
  let playing = true, t = 0, last = performance.now();
  button.onclick = () => { playing = !playing; button.textContent = playing ? "Pause" : "Play"; };
  slider.oninput = () => { t = parseFloat(slider.value); playing = false; button.textContent = "Play"; };
  box.querySelector(".view3d-from").onchange = e => e.target.value ? cameraView(e.target.value) : freeView();
  function show(time) {
    mixer.setTime(time);
    renderer.render(scene, view);
  }
  function pixels() {
    const gl = renderer.getContext();
    const px = new Uint8Array(W * H * 4);
    gl.readPixels(0, 0, W, H, gl.RGBA, gl.UNSIGNED_BYTE, px);
    return px;
  }
  // self-check for the headless test: the first frame and the middle one differ
  show(0); const a = pixels(); show(duration / 2); const b = pixels();
  let differ = 0;
  for (let i = 0; i < a.length; i += 4) if (a[i] !== b[i] || a[i + 1] !== b[i + 1] || a[i + 2] !== b[i + 2]) differ++;
  box.dataset.framesDiffer = String(differ);
  box.dataset.view3d = "ready";
  function tick(now) {
    if (playing && duration > 0) { t = (t + (now - last) / 1000) % duration; slider.value = t; }
    last = now;
    clock.textContent = t.toFixed(2) + " s";
    controls.update();
    show(t);
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);
}, err => { box.dataset.view3d = "error: " + err; });
"""

CSS = """
.view3d { margin: 12px 0; }
.view3d canvas { border: 1px solid #dde1e6; border-radius: 3px; display: block; max-width: 100%; }
.view3d-bar { display: flex; gap: 10px; align-items: center; margin-top: 6px; font-size: 13px; }
.view3d-time { flex: 1; }
.view3d-clock { font-variant-numeric: tabular-nums; min-width: 64px; }
"""


def _strided(result, max_frames: int):
    """The result on at most ``max_frames`` evenly strided frames."""
    import numpy as np

    if result.num_frames <= max_frames:
        return result
    return result.take(np.linspace(0, result.num_frames - 1, max_frames).round().astype(int))


def viewer_html(people, model, rig, colours: dict) -> tuple[str | None, str]:
    """(HTML of the view or None, a caption or what is missing) for [(person id, SmplxResult)]."""
    import tempfile

    from mamma_kit.export.gltf import write_gltf

    root = three_dir()
    if root is None:
        return None, ("the 3D view needs three.js: run `npm ci` in the mamma-kit folder (`make env` does), "
                      f"or set {THREE_ENV} to a three.js package folder")
    people = [(k, _strided(r, MAX_FRAMES)) for k, r in people]
    with tempfile.TemporaryDirectory() as tmp:
        summary = write_gltf(Path(tmp) / "view.glb", people, model, rig, colours=colours)
        glb = (Path(tmp) / "view.glb").read_bytes()
    cams = rig.names if rig is not None else []
    strided = any(r.num_frames >= MAX_FRAMES for _, r in people)
    caption = (f"The fitted bodies ({len(people)}), the calibrated cameras and the floor over {summary['seconds']:.1f} s"
               + (f" (at most {MAX_FRAMES} frames per person)" if strided else "")
               + ": drag to orbit, scroll to zoom, the slider to scrub; the menu shows a camera's view. "
               "The same scene as export/capture.glb (Blender: File > Import > glTF 2.0).")
    return _html(glb, import_map(root), cams, summary["seconds"]), caption
