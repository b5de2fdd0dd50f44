// The camera's pose drawn in 3D around the object, with three.js (vendored under
// static/vendor/three, see its SOURCE.md; the page's import map names it "three").
//
// Everything is drawn in the object frame of docs/pose.md, in centimetres: origin at the centre
// of the object's rectangle, the object in z = 0, +x to the right and +y up on its texture, +z
// out of the printed face. The viewer looks at that frame with +z up, so the object lies like a
// sheet on a table and the cameras hover above it.
//
// All result cards share one WebGL renderer (browsers allow a handful of WebGL contexts per
// page): each card's scene is rendered there and copied into the card's own 2D canvas.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

const VIEW = { width: 480, height: 360 };                      // CSS px of a card's 3D view
const DEFAULT_OBJECT_CM = { width: 26, height: 18 };           // a card without a profile
const DEFAULT_Z_SPLIT_CM = 60;                                 // service/core/regions.py
const DEFAULT_IMAGE_PX = [640, 480];                           // an answer without image_size
const COLOURS = {
  background: 0xffffff, objectFront: 0xe9edf3, objectBack: 0x8c95a3, outline: 0x1d2430,
  corner0: 0x2ec4b6, regions: 0xaab3c0, lit: 0xf4a300, camera: 0x2a6fdb, distance: 0x5b6575,
};

let renderer;  // the shared renderer: undefined until first needed, null without WebGL

function sharedRenderer() {
  if (renderer === undefined) {
    try {
      renderer = new THREE.WebGLRenderer({ antialias: true });
      renderer.setPixelRatio(window.devicePixelRatio || 1);
      renderer.setSize(VIEW.width, VIEW.height, false);
    } catch (_) {
      renderer = null;  // no WebGL in this browser: the cards say so
    }
  }
  return renderer;
}

// --- geometry ------------------------------------------------------------------------------

const vec = (p) => new THREE.Vector3(p[0], p[1], p[2]);

// Rows of R(rvec) (Rodrigues): X_cam = R X_obj + t. Row k is the camera's axis k in the object
// frame: row 0 its x (image right), row 1 its y (image down), row 2 its optical axis.
function cameraAxes(rvec) {
  const axis = vec(rvec);
  const angle = axis.length();
  if (angle < 1e-12) return [vec([1, 0, 0]), vec([0, 1, 0]), vec([0, 0, 1])];
  axis.divideScalar(angle);
  // THREE's rotation matrix is R itself; its rows are the columns of the transpose
  const r = new THREE.Matrix4().makeRotationAxis(axis, angle).transpose();
  const rows = [new THREE.Vector3(), new THREE.Vector3(), new THREE.Vector3()];
  r.extractBasis(...rows);
  return rows;
}

// The box the view spans (cm): x and y in -half..half, z in 0..top, round the object and over
// the near/far split, grown to hold the camera; in steps of 10 cm, so that a moving camera
// (the webcam) seldom changes it.
function sceneBox(pose, objectSize, zSplit) {
  let half = 0.75 * objectSize;
  let top = 1.15 * zSplit;
  if (pose) {
    const [x, y, z] = pose.camera_cm;
    half = Math.max(half, 1.1 * Math.abs(x), 1.1 * Math.abs(y));
    top = Math.max(top, 1.1 * z);
  }
  const step = (v) => Math.ceil(v / 10) * 10;
  return { half: step(half), top: step(top) };
}

function lines(points, colour, options = {}) {
  const geometry = new THREE.BufferGeometry().setFromPoints(points);
  const material = options.dashed
    ? new THREE.LineDashedMaterial({ color: colour, dashSize: 2, gapSize: 1.5 })
    : new THREE.LineBasicMaterial({ color: colour, transparent: !!options.opacity,
      opacity: options.opacity ?? 1 });
  const segments = new THREE.LineSegments(geometry, material);
  if (options.dashed) segments.computeLineDistances();
  return segments;
}

// The 8 corners of an axis-aligned box; corner i takes hi on axis k where bit k of i is set.
function boxCorners(lo, hi) {
  return [...Array(8).keys()].map((i) => vec([0, 1, 2].map((k) => (i >> k) & 1 ? hi[k] : lo[k])));
}

// Segments (pairs of points) along the edges of an axis-aligned box.
function boxEdges(lo, hi) {
  const corner = boxCorners(lo, hi);
  const edges = [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];
  return edges.flatMap(([a, b]) => [corner[a], corner[b]]);
}

// --- the scene's parts -----------------------------------------------------------------------

// The object: its rectangle (its picture on the front, +z, where the model has one (an
// image URL), else light; darker back), outline and a dot on corner 0, the (-x, -y) one, as
// on the photo.
function objectPart(width, height, picture, redraw) {
  const group = new THREE.Group();
  const plane = new THREE.PlaneGeometry(width, height);
  const front = picture
    ? { map: new THREE.TextureLoader().load(picture, redraw), side: THREE.FrontSide }
    : { color: COLOURS.objectFront, side: THREE.FrontSide };
  if (front.map) front.map.colorSpace = THREE.SRGBColorSpace;
  group.add(new THREE.Mesh(plane, new THREE.MeshBasicMaterial(front)));
  group.add(new THREE.Mesh(plane, new THREE.MeshBasicMaterial({ color: COLOURS.objectBack, side: THREE.BackSide })));
  const [w, h] = [width / 2, height / 2];
  const rim = [[-w, -h], [w, -h], [w, h], [-w, h]].map(([x, y]) => vec([x, y, 0]));
  group.add(lines(rim.flatMap((p, i) => [p, rim[(i + 1) % 4]]), COLOURS.outline));
  const dot = new THREE.Mesh(new THREE.SphereGeometry(Math.max(width, height) / 40, 12, 8),
    new THREE.MeshBasicMaterial({ color: COLOURS.corner0 }));
  dot.position.set(-w, -h, 0);
  group.add(dot);
  group.add(new THREE.AxesHelper(Math.max(width, height) * 0.45));  // x red, y green, z blue
  return group;
}

// The 8 regions (docs/SPEC.md): octants split at x = 0, y = 0 and z = z_split, as a faint
// wireframe box over z = 0..top; the answered class's octant tinted.
function regionsPart(box, zSplit, classId) {
  const { half: a, top } = box;
  const group = new THREE.Group();
  const splits = [
    ...boxEdges([-a, -a, 0], [a, a, top]),
    ...boxEdges([0, -a, 0], [0, a, top]),   // the plane x = 0
    ...boxEdges([-a, 0, 0], [a, 0, top]),   // the plane y = 0
    ...boxEdges([-a, -a, zSplit], [a, a, zSplit]),
  ];
  group.add(lines(splits, COLOURS.regions, { opacity: 0.55 }));
  if (classId >= 1 && classId <= 8) {
    const { centre, size } = octant(classId, a, top, zSplit);
    const tint = new THREE.Mesh(new THREE.BoxGeometry(...size), new THREE.MeshBasicMaterial({
      color: COLOURS.lit, transparent: true, opacity: 0.12, depthWrite: false }));
    tint.position.copy(centre);
    group.add(tint);
  }
  return group;
}

// Centre and size of class k's octant within the drawn box: quadrant (k - 1) % 4 + 1 gives
// the x/y signs (1: ++, 2: -+, 3: --, 4: +-), k > 4 the far half (z >= z_split).
function octant(k, half, top, zSplit) {
  const [sx, sy] = [[1, 1], [-1, 1], [-1, -1], [1, -1]][(k - 1) % 4];
  const [z0, z1] = k > 4 ? [zSplit, top] : [0, zSplit];
  return { centre: vec([sx * half / 2, sy * half / 2, (z0 + z1) / 2]), size: [half, half, z1 - z0] };
}

// The camera as a pyramid whose opening is its field of view (the image's size [W, H] px over
// fx), with a small triangle on its top edge (the image's up), and its optical axis as a
// dashed line down to the object's plane.
function cameraPart(pose, [width, height]) {
  const [right, down, forward] = cameraAxes(pose.rvec);
  const c = vec(pose.camera_cm);
  const distance = pose.distance_cm;
  const depth = THREE.MathUtils.clamp(0.3 * distance, 6, 30);
  const tanX = width / 2 / pose.fx;
  const tanY = height / 2 / pose.fx;
  // the point `depth` in front of the camera at image-plane offsets (u, v) (tangents)
  const ahead = (u, v) => c.clone().addScaledVector(forward, depth)
    .addScaledVector(right, u * depth).addScaledVector(down, v * depth);
  const base = [ahead(-tanX, -tanY), ahead(tanX, -tanY), ahead(tanX, tanY), ahead(-tanX, tanY)];
  const segments = base.flatMap((p, i) => [c, p, p, base[(i + 1) % 4]]);
  const up = ahead(0, -tanY * 1.5);  // the triangle above the image's top edge
  segments.push(ahead(-tanX / 2, -tanY), up, up, ahead(tanX / 2, -tanY));
  const group = new THREE.Group();
  group.add(lines(segments, COLOURS.camera));
  const sides = new THREE.BufferGeometry().setFromPoints(base.flatMap((p, i) => [c, p, base[(i + 1) % 4]]));
  group.add(new THREE.Mesh(sides, new THREE.MeshBasicMaterial({ color: COLOURS.camera,
    transparent: true, opacity: 0.25, side: THREE.DoubleSide, depthWrite: false })));
  const hit = -c.z / forward.z;  // where the optical axis meets z = 0 (if in front)
  const reach = hit > 0 && Number.isFinite(hit) ? hit : distance;
  group.add(lines([c, c.clone().addScaledVector(forward, reach)], COLOURS.camera, { dashed: true }));
  const centre = new THREE.Mesh(new THREE.SphereGeometry(depth / 12, 12, 8),
    new THREE.MeshBasicMaterial({ color: COLOURS.camera }));
  centre.position.copy(c);
  group.add(centre);
  group.add(lines([vec([0, 0, 0]), c], COLOURS.distance));  // the distance, labelled
  return group;
}

// The direction (unit, object frame) the viewer first looks from: 20 degrees above the
// object's plane, and 60 degrees of azimuth clockwise from the camera (if any), which is then
// seen from its side, a little in front; without a pose, from the object's lower right.
function firstViewpoint(pose) {
  const azimuth = THREE.MathUtils.degToRad(pose ? pose.azimuth_deg - 60 : -60);
  const elevation = THREE.MathUtils.degToRad(20);
  return vec([Math.cos(elevation) * Math.cos(azimuth), Math.cos(elevation) * Math.sin(azimuth),
    Math.sin(elevation)]);
}

function disposeAll(object) {
  object.traverse((part) => {
    if (part.geometry) part.geometry.dispose();
    if (part.material && part.material.map) part.material.map.dispose();
    if (part.material) part.material.dispose();
  });
}

// --- one card's view -------------------------------------------------------------------------

// The view in `container` (a .scene element holding canvas.pose-3d, .scene-labels and
// .scene-note): show(answer) draws it; dragging it turns the viewer round the object.
export class PoseView {
  constructor(container) {
    this.container = container;
    this.canvas = container.querySelector("canvas.pose-3d");
    this.labels = container.querySelector(".scene-labels");
    this.note = container.querySelector(".scene-note");
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(COLOURS.background);
    this.viewer = new THREE.PerspectiveCamera(35, VIEW.width / VIEW.height, 1, 5000);
    this.viewer.up.set(0, 0, 1);
    this.controls = null;  // the mouse's orbit, made with the first drawing
    this.box = null;       // the box in sight, {half, top} (cm)
    this.tags = [];        // [{element, at: Vector3}]: HTML labels pinned to scene points
  }

  // Draw `result` (a /v1/predict result or a stream message) for a model whose card has
  // `profile` (object size, near/far split; {}: defaults) and whose object looks like
  // `picture` (an image URL; null: a plain rectangle).
  show(result, profile, picture = null) {
    const pose = result.pose || null;
    this.container.dataset.pose = pose ? "yes" : "no";
    if (!sharedRenderer()) {
      this.setNote("This browser gives the page no WebGL: no 3D view.");
      return;
    }
    const object = { width: profile.width_cm || DEFAULT_OBJECT_CM.width,
      height: profile.height_cm || DEFAULT_OBJECT_CM.height };
    const zSplit = profile.z_split_cm || DEFAULT_Z_SPLIT_CM;
    const box = sceneBox(pose, Math.max(object.width, object.height), zSplit);
    this.clear();
    this.scene.add(objectPart(object.width, object.height, picture, () => this.render()),
      regionsPart(box, zSplit, result.class_id));
    this.tagRegions(object, box, zSplit);
    if (pose) {
      this.scene.add(cameraPart(pose, result.image_size || DEFAULT_IMAGE_PX));
      this.tag(distanceText(pose), vec(pose.camera_cm).multiplyScalar(0.5), "distance-label");
    }
    this.setNote(pose ? "" : noPoseReason(result));
    if (!this.box || this.box.half !== box.half || this.box.top !== box.top) this.frame(box, pose);
    this.render();
  }

  clear() {
    for (const child of [...this.scene.children]) {
      this.scene.remove(child);
      disposeAll(child);
    }
    this.labels.replaceChildren();
    this.tags = [];
  }

  // The axes' names at their tips and the class number of each octant at its centre.
  tagRegions(object, box, zSplit) {
    const axis = Math.max(object.width, object.height) * 0.5;
    this.tag("x", vec([axis, 0, 0]), "axis-tag");
    this.tag("y", vec([0, axis, 0]), "axis-tag");
    this.tag("z", vec([0, 0, axis]), "axis-tag");
    for (let k = 1; k <= 8; k++) {
      this.tag(String(k), octant(k, box.half, box.top, zSplit).centre, "octant-tag");
    }
  }

  tag(text, at, className) {
    const element = document.createElement("span");
    element.className = className;
    element.textContent = text;
    this.labels.append(element);
    this.tags.push({ element, at });
  }

  setNote(text) {
    this.note.textContent = text;
    this.note.hidden = !text;
  }

  // Aim the viewer at the centre of `box` from where it is (at first: from `pose`'s side),
  // as close as it can be with the whole box in sight.
  frame(box, pose) {
    const { half: a, top } = box;
    const target = vec([0, 0, top / 2]);
    const away = this.controls
      ? this.viewer.position.clone().sub(this.controls.target).normalize()
      : firstViewpoint(pose);
    this.viewer.position.copy(target).add(away);
    this.viewer.lookAt(target);
    this.viewer.updateMatrixWorld();
    // Stepping back by s along `away` leaves a point's (x, y) in the viewer's frame as they
    // are and adds s to its depth: the step that brings every corner of the box in sight.
    const tanY = Math.tan(THREE.MathUtils.degToRad(this.viewer.fov / 2));
    const tanX = tanY * this.viewer.aspect;
    let step = 0;
    for (const corner of boxCorners([-a, -a, 0], [a, a, top])) {
      const p = corner.applyMatrix4(this.viewer.matrixWorldInverse);  // depth = -p.z
      step = Math.max(step, 1.04 * Math.max(Math.abs(p.x) / tanX, Math.abs(p.y) / tanY) + p.z);
    }
    this.viewer.position.addScaledVector(away, step);
    if (!this.controls) {
      this.controls = new OrbitControls(this.viewer, this.canvas);
      this.controls.enableZoom = false;  // the wheel keeps scrolling the page
      this.controls.enablePan = false;
      this.controls.addEventListener("change", () => this.render());
    }
    this.controls.target.copy(target);
    this.controls.update();
    this.box = box;
  }

  // Render through the shared renderer, copy into this card's canvas, move the labels.
  render() {
    const gl = sharedRenderer();
    gl.render(this.scene, this.viewer);
    const { width, height } = gl.domElement;  // device pixels
    if (this.canvas.width !== width || this.canvas.height !== height) {
      [this.canvas.width, this.canvas.height] = [width, height];
    }
    this.canvas.getContext("2d").drawImage(gl.domElement, 0, 0);
    for (const { element, at } of this.tags) {
      const p = at.clone().project(this.viewer);  // normalised device coordinates, -1..1
      element.style.visibility = p.z > 1 ? "hidden" : "visible";  // behind the viewer
      element.style.left = `${((p.x + 1) / 2) * 100}%`;
      element.style.top = `${((1 - p.y) / 2) * 100}%`;
    }
  }
}

// "58.8 cm" and, where fx was estimated, the distances its range allows: "58.8 cm (52–67)".
export function distanceText(pose) {
  const range = pose.distance_range_cm ? ` (${rangeText(pose.distance_range_cm)})` : "";
  return `${pose.distance_cm.toFixed(1)} cm${range}`;
}

export function rangeText([low, high]) {
  return `${low.toFixed(0)}–${high.toFixed(0)}`;
}

function noPoseReason(result) {
  if (result.class_id === 0) return "No pose: the object is not in view.";
  if (!result.corners) return "No pose: only a corner model in whole-image mode gives one.";
  return "No pose in this answer.";
}
