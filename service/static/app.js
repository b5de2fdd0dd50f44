// The planar-pose web page: photos go to POST /v1/predict, webcam frames to WS /v1/stream.
// Plain JavaScript modules, no build step, nothing loaded from another host (three.js, for the
// 3D view of the pose, is vendored under static/vendor/three).
import { PoseView, distanceText, rangeText } from "./pose-view.js";

const SVG_NS = "http://www.w3.org/2000/svg";
const $ = (selector, root = document) => root.querySelector(selector);

// Quadrant 1..4 -> (x side, y side) as in service/regions.py; class = quadrant (+4 when far).
const QUADRANTS = { 1: ["+", "+"], 2: ["-", "+"], 3: ["-", "-"], 4: ["+", "-"] };

function regionOf(classId) {
  if (classId === 0) return { present: false, label: "object not in view" };
  const depth = classId <= 4 ? "near" : "far";
  const [x, y] = QUADRANTS[((classId - 1) % 4) + 1];
  return { present: true, depth, x, y, label: `${depth}, x${x}, y${y}` };
}

// card: the chosen model's; models: GET /v1/models by name; picture: an object URL of the
// chosen model's picture of its object (null: it has none, the diagrams draw a checkerboard).
const state = { card: null, camera: null, models: { default: "", byName: {} }, picture: null };
const poseViews = new WeakMap();  // result card -> its PoseView

// --- errors in plain words -------------------------------------------------------------

const PLAIN = {
  unauthorized: "This service needs an API key: type it in the API key field, then try again.",
  undecodable_image: "The service could not read this file as an image (JPEG, PNG, WebP, BMP or GIF).",
  unsupported_media_type: "This kind of file is not accepted: send a JPEG, PNG, WebP, BMP or GIF image.",
  payload_too_large: "The file is too large for the service.",
  image_too_large: "The image has more pixels than the service accepts.",
  too_many_images: "Too many images in one request.",
  invalid_parameters: "The request had a bad setting.",
  not_ready: "The model is not loaded yet; try again in a few seconds.",
  model_not_found: "The service does not serve this model.",
  internal_error: "The service failed on this request (the error is in its log).",
  network: "Cannot reach the service: is it still running?",
  camera: "The webcam could not be started.",
  camera_not_found: "The service has no such camera any more: pick another in the Camera list, or none.",
  camera_store_unavailable: "The service cannot read its cameras now; try again, or type fx instead.",
};

function explain(code, message) {
  const plain = PLAIN[code] || "The service refused the request.";
  return message ? `${plain} (${message})` : plain;
}

function showError(text) {
  const box = $("#error");
  box.textContent = text;
  box.hidden = !text;
}

async function errorOf(response) {
  try {
    const body = await response.json();
    if (body && body.error) return explain(body.error.code, body.error.message);
  } catch (_) { /* not JSON */ }
  return explain("", `HTTP ${response.status} ${response.statusText}`);
}

function apiKey() {
  return $("#api-key").value.trim();
}

function authHeaders() {
  const key = apiKey();
  return key ? { "X-API-Key": key } : {};
}

// --- the models and the chosen one's card ----------------------------------------------

// The served model chosen in the Object list ("" for the default model).
function chosenModel() {
  return $("#model-name").value;
}

// The query that sends a request to the chosen model ("" for the default model).
function modelQuery() {
  return chosenModel() ? `model=${encodeURIComponent(chosenModel())}` : "";
}

// The query of a prediction (photos and the stream): mode, model, and the focal length typed
// in (fx=, px) or the learned camera picked (camera=ID), which exclude each other.
function predictParams() {
  const params = new URLSearchParams({ mode: $("#mode").value });
  if (chosenModel()) params.set("model", chosenModel());
  const fx = $("#fx").value.trim();
  if (fx) params.set("fx", fx);
  else if ($("#learned-camera").value) params.set("camera", $("#learned-camera").value);
  return params;
}

// Fill the Object list from GET /v1/models: one entry per served model, its object named.
async function loadModels() {
  let response;
  try {
    response = await fetch("v1/models", { headers: authHeaders() });
  } catch (_) {
    return;
  }
  if (!response.ok) return;
  const select = $("#model-name");
  const chosen = select.value;
  const models = (await response.json()).models || [];
  if (!models.length) return;
  // the default model first, as "" (the requests then name no model)
  models.sort((a, b) => Number(b.default) - Number(a.default));
  state.models = { default: models[0].default ? models[0].name : "",
    byName: Object.fromEntries(models.map((m) => [m.name, m])) };
  select.replaceChildren(...models.map((m) => new Option(
    `${m.profile || "object"}: ${m.name}${m.default ? " (default)" : ""}${m.training === "zero-shot" ? " — zero-shot" : ""}`,
    m.default ? "" : m.name)));
  select.value = chosen;
}

// The chosen model's picture of its object (GET /v1/models/{name}/texture) as an object URL
// in state.picture, for the diagrams; null where it has none or the request fails.
async function loadPicture() {
  const name = chosenModel() || state.models.default;
  if (state.picture) URL.revokeObjectURL(state.picture);
  state.picture = null;
  if (!name) return;
  try {
    const response = await fetch(`v1/models/${encodeURIComponent(name)}/texture`, { headers: authHeaders() });
    if (response.ok) state.picture = URL.createObjectURL(await response.blob());
  } catch (_) {
    // no picture: the diagrams draw a checkerboard
  }
}

async function loadCard() {
  const status = $("#model-status");
  status.hidden = false;
  status.textContent = "Loading the model card…";
  let response;
  try {
    response = await fetch(`v1/model?${modelQuery()}`, { headers: authHeaders() });
  } catch (_) {
    status.textContent = explain("network");
    return;
  }
  if (!response.ok) {
    status.textContent = await errorOf(response);
    return;
  }
  state.card = await response.json();
  status.hidden = true;
  renderCard(state.card);
}

// The card's measured accuracies as a table: data set, kind, images, accuracy.
function accuracyTable(accuracy) {
  const table = document.createElement("table");
  table.className = "accuracy";
  const rows = [["data set", "kind", "images", "right"]];
  for (const [name, a] of Object.entries(accuracy || {})) {
    const kind = name.startsWith("real") ? "real photos" : "synthetic";
    rows.push([name, `${kind}, ${a.split || "test"}`, String(a.count ?? "—"),
      typeof a.accuracy === "number" ? `${(100 * a.accuracy).toFixed(1)} %` : "—"]);
  }
  rows.forEach((cells, i) => {
    const tr = table.insertRow();
    for (const text of cells) {
      const cell = document.createElement(i === 0 ? "th" : "td");
      cell.textContent = text;
      tr.append(cell);
    }
  });
  return table;
}

// --- learned cameras (GET /v1/cameras) ----------------------------------------------------

// Fill the Camera list with the cameras the service learned; hidden where it has none to
// offer (no such route, refused, unreachable).
async function loadCameras() {
  const label = $("#learned-camera-choice");
  const select = $("#learned-camera");
  let cameras = null;
  try {
    const response = await fetch("v1/cameras", { headers: authHeaders() });
    if (response.ok) cameras = (await response.json()).cameras || [];
  } catch (_) { /* unreachable: as without the route */ }
  const chosen = select.value;
  select.replaceChildren(new Option("none", ""), ...(cameras || []).map((c) => new Option(
    `${c.name || c.id} (fx ${Math.round(c.fx)} px${c.width ? ` at ${c.width} px wide` : ""})`, c.id)));
  select.value = chosen;
  if (select.value !== chosen) select.value = "";  // that camera is gone
  label.hidden = cameras === null;
}

// A focal length typed in and a learned camera exclude each other: setting one clears the other.
function setUpFocal() {
  const fx = $("#fx");
  const camera = $("#learned-camera");
  fx.addEventListener("input", () => { if (fx.value) camera.value = ""; });
  camera.addEventListener("change", () => { if (camera.value) fx.value = ""; });
}

function renderCard(card) {
  const list = $("#model-card");
  const profile = card.profile || {};
  const size = profile.width_cm ? ` (${profile.width_cm} × ${profile.height_cm} cm)` : "";
  const rows = [
    ["model", `${card.name} ${card.version || ""}`.trim()],
    ["object", `${profile.name || "unknown"}${size}`],
    ["training", trainingText(card)],
    ["input size", `${card.input[0]} × ${card.input[1]} px`],
    ["near / far split", profile.z_split_cm ? `${profile.z_split_cm} cm from the object` : "—"],
  ];
  list.replaceChildren();
  for (const [term, value] of rows) addTerm(list, term, [value]);
  addTerm(list, "measured accuracy", [Object.keys(card.accuracy || {}).length ? accuracyTable(card.accuracy) : "—"]);
  list.hidden = false;
}

// How the model knows its object (service/pipeline/model.py `training_of`), with what its
// zero-shot presence threshold measured.
function trainingText(card) {
  const z = card.zero_shot;
  if (z) {
    const pct = (v) => (typeof v === "number" ? `${(100 * v).toFixed(1)} %` : "—");
    return "zero-shot: the generic corner network with this object's picture, not trained on it " +
      `(presence threshold ${Number(z.presence_threshold).toFixed(2)} on ${z.threshold_renders} renders: ` +
      `present right ${pct(z.present_right)}, absent right ${pct(z.absent_right)}); ` +
      "planar-pose object train fine-tunes it";
  }
  if (String(card.architecture || "").startsWith("corners-any")) {
    return "fine-tuned on this object from the generic corner network";
  }
  return "trained on this object";
}

function addTerm(list, term, values) {
  const dt = document.createElement("dt");
  dt.textContent = term;
  list.append(dt);
  for (const value of values.length ? values : ["—"]) {
    const dd = document.createElement("dd");
    if (typeof value === "string") dd.textContent = value;
    else dd.append(value);
    dd.dataset.term = term;
    list.append(dd);
  }
}

// --- one answer: image with box, words, octants, bars ----------------------------------

function newResultCard(title) {
  const card = $("#result-template").content.firstElementChild.cloneNode(true);
  $(".name", card).textContent = title;
  return card;
}

function drawView(canvas, source, width, height, result) {
  const scale = Math.min(1, 480 / width);
  canvas.width = Math.round(width * scale);
  canvas.height = Math.round(height * scale);
  const ctx = canvas.getContext("2d");
  ctx.drawImage(source, 0, 0, canvas.width, canvas.height);
  if (!result) return;
  for (const det of (result.detections || []).slice(1)) {
    strokeBox(ctx, det.box, scale, "rgba(255, 200, 0, 0.9)", 1.5, [6, 4]);
  }
  if (result.box) strokeBox(ctx, result.box, scale, "#e5383b", 3, []);
  if (result.corners) strokeCorners(ctx, result.corners, scale);
}

// The object's outline from its four corners; a dot on corner 0, the (-X,-Y) one.
function strokeCorners(ctx, corners, scale) {
  ctx.save();
  ctx.strokeStyle = "#2ec4b6";
  ctx.fillStyle = "#2ec4b6";
  ctx.lineWidth = 2;
  ctx.beginPath();
  corners.forEach(([x, y], i) => (i ? ctx.lineTo : ctx.moveTo).call(ctx, x * scale, y * scale));
  ctx.closePath();
  ctx.stroke();
  ctx.beginPath();
  ctx.arc(corners[0][0] * scale, corners[0][1] * scale, 4, 0, 2 * Math.PI);
  ctx.fill();
  ctx.restore();
}

function strokeBox(ctx, box, scale, colour, width, dash) {
  ctx.save();
  ctx.strokeStyle = colour;
  ctx.lineWidth = width;
  ctx.setLineDash(dash);
  ctx.strokeRect(box.x * scale, box.y * scale, box.w * scale, box.h * scale);
  ctx.restore();
}

function showAnswer(card, result) {
  card.dataset.classId = String(result.class_id);
  const region = $(".region", card);
  region.textContent = result.region.present
    ? `Camera is ${result.region.label.replace(/, /g, " · ")}`
    : "Object not in view";
  region.dataset.label = result.region.label;
  const where = result.box ? ` · box ${result.box.w}×${result.box.h} at (${result.box.x}, ${result.box.y})` : "";
  $(".meta", card).textContent =
    `class ${result.class_id} · confidence ${(100 * result.confidence).toFixed(1)} %` +
    ` · ${result.elapsed_ms.toFixed(1)} ms${where}${focalText(result)}`;
  showPoseText(card, result);
  $(".octants", card).replaceChildren(octantPicture(result.class_id));
  $(".bars", card).replaceChildren(probabilityBars(result.probabilities, result.class_id));
  $(".result-error", card).hidden = true;
}

// " · fx 1480 px (estimated, 1310–1702)": the focal length the pose used, where it came from
// and, when estimated, the range the view allows; the answer's own fx without a pose.
function focalText(result) {
  const pose = result.pose;
  const fx = pose ? pose.fx : result.fx;
  if (fx == null) return "";
  const source = pose ? pose.fx_source : result.fx_source;
  const range = pose && pose.fx_range ? `, ${rangeText(pose.fx_range)}` : "";
  return ` · fx ${fx.toFixed(0)} px (${source}${range})`;
}

// The pose in words: where the camera is (object frame, cm), how far, from which direction;
// the finer region's cell when the answer has one.
function showPoseText(card, result) {
  const box = $(".pose-text", card);
  const pose = result.pose;
  box.hidden = !pose;
  if (!pose) return;
  const [x, y, z] = pose.camera_cm.map((v) => v.toFixed(1));
  const lines = [
    `Camera at x ${x}, y ${y}, z ${z} cm from the object's centre, ${distanceText(pose)} away`,
    `azimuth ${pose.azimuth_deg.toFixed(0)}° · elevation ${pose.elevation_deg.toFixed(0)}°` +
      (pose.residual_px != null ? ` · corners fit to ${pose.residual_px.toFixed(1)} px` : ""),
  ];
  if (result.cell) {
    const p = result.cell.probability;
    lines.push(`cell ${result.cell.index}: ${result.cell.label}${p != null ? ` (${(100 * p).toFixed(0)} %)` : ""}`);
  }
  box.replaceChildren(...lines.flatMap((line, i) => (i ? [document.createElement("br"), line] : [line])));
}

// The 3D view of the card: the object, the 8 regions and, with a pose, the camera.
function showPose(card, result) {
  let view = poseViews.get(card);
  if (!view) {
    view = new PoseView($(".scene", card));
    poseViews.set(card, view);
  }
  view.show(result, (state.card && state.card.profile) || {}, state.picture);
}

function showResultError(card, text) {
  const box = $(".result-error", card);
  box.textContent = text;
  box.hidden = false;
  card.classList.add("failed");
}

function svg(name, attrs, text) {
  const el = document.createElementNS(SVG_NS, name);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  if (text !== undefined) el.textContent = text;
  return el;
}

// Two panels (near, far), each the object seen face on with its 4 quadrants around it:
// x to the right, y up, as in the object frame of docs/SPEC.md.
function octantPicture(classId) {
  const root = svg("svg", { viewBox: "0 0 360 172", class: "octant-picture", role: "img",
    "data-lit": String(classId), "aria-label": `region: ${regionOf(classId).label}` });
  ["near", "far"].forEach((depth, i) => root.append(octantPanel(depth, i * 180, classId)));
  if (classId === 0) {
    root.append(svg("text", { x: 180, y: 92, class: "none-label" }, "object not in view"));
  }
  return root;
}

function octantPanel(depth, left, classId) {
  const g = svg("g", { transform: `translate(${left}, 0)` });
  g.append(svg("text", { x: 90, y: 13, class: "panel-title" }, `${depth} (${depth === "near" ? "z < split" : "z ≥ split"})`));
  for (let q = 1; q <= 4; q++) {
    const id = depth === "near" ? q : q + 4;
    const [x, y] = QUADRANTS[q];
    const cell = svg("rect", { x: x === "+" ? 90 : 20, y: y === "+" ? 20 : 90, width: 70, height: 70,
      class: id === classId ? "octant lit" : "octant", "data-class": String(id) });
    cell.append(svg("title", {}, regionOf(id).label));
    g.append(cell);
    g.append(svg("text", { x: x === "+" ? 148 : 32, y: y === "+" ? 36 : 154, class: "octant-id" }, String(id)));
  }
  // the object face on at the panel's centre (90, 90), 40 wide, as tall as its card says
  const profile = (state.card && state.card.profile) || {};
  const h = profile.width_cm ? Math.min(40, (40 * profile.height_cm) / profile.width_cm) : 28;
  const w = profile.width_cm ? (h * profile.width_cm) / profile.height_cm : 40;
  g.append((state.picture ? picture : board)(90 - w / 2, 90 - h / 2, w, h));
  g.append(svg("text", { x: 170, y: 94, class: "axis" }, "x+"));
  g.append(svg("text", { x: 10, y: 94, class: "axis" }, "x−"));
  g.append(svg("text", { x: 90, y: 31, class: "axis" }, "y+"));
  g.append(svg("text", { x: 90, y: 170, class: "axis" }, "y−"));
  return g;
}

// The object's own picture, face on, in the box (x, y, w, h).
function picture(x, y, w, h) {
  const g = svg("g", { class: "board" });
  g.append(svg("image", { x, y, width: w, height: h, href: state.picture, preserveAspectRatio: "none" }));
  g.append(svg("rect", { x, y, width: w, height: h, class: "picture-frame" }));
  return g;
}

function board(x, y, w, h) {
  const g = svg("g", { class: "board" });
  g.append(svg("rect", { x, y, width: w, height: h, class: "board-frame" }));
  const n = 4, m = 3;
  for (let i = 0; i < n; i++) {
    for (let j = 0; j < m; j++) {
      if ((i + j) % 2) continue;
      g.append(svg("rect", { x: x + (i * w) / n, y: y + (j * h) / m, width: w / n, height: h / m,
        class: "board-square" }));
    }
  }
  return g;
}

function probabilityBars(probabilities, chosen) {
  const list = document.createElement("div");
  list.className = "bar-list";
  probabilities.forEach((p, k) => {
    const row = document.createElement("div");
    row.className = k === chosen ? "bar-row chosen" : "bar-row";
    row.dataset.class = String(k);
    const label = document.createElement("span");
    label.className = "bar-label";
    label.textContent = `${k} · ${regionOf(k).label}`;
    const bar = document.createElement("span");
    bar.className = "bar";
    const fill = document.createElement("span");
    fill.className = "fill";
    fill.style.width = `${(100 * p).toFixed(1)}%`;
    bar.append(fill);
    const value = document.createElement("span");
    value.className = "bar-value";
    value.textContent = `${(100 * p).toFixed(1)} %`;
    row.append(label, bar, value);
    list.append(row);
  });
  return list;
}

// --- photos ----------------------------------------------------------------------------

async function predictFiles(files) {
  showError("");
  $("#results-title").hidden = false;
  for (const file of files) await predictFile(file);
}

async function predictFile(file) {
  const card = newResultCard(file.name || "photo");
  card.dataset.state = "pending";
  $("#results").prepend(card);
  const form = new FormData();
  form.append("image", file, file.name || "photo");
  let response;
  try {
    response = await fetch(`v1/predict?${predictParams()}`, {
      method: "POST", body: form, headers: authHeaders() });
  } catch (_) {
    showResultError(card, explain("network"));
    card.dataset.state = "error";
    return;
  }
  if (!response.ok) {
    showResultError(card, await errorOf(response));
    card.dataset.state = "error";
    return;
  }
  const result = (await response.json()).results[0];
  showAnswer(card, result);
  showPose(card, result);
  await drawPhoto($(".view", card), file, result);
  card.dataset.state = "done";
}

async function drawPhoto(canvas, file, result) {
  try {
    const bitmap = await createImageBitmap(file, { imageOrientation: "from-image" });
    drawView(canvas, bitmap, bitmap.width, bitmap.height, result);
    bitmap.close();
  } catch (_) {
    canvas.hidden = true;  // the service read it, the browser cannot show it (e.g. 16-bit PNG)
  }
}

function setUpDrop() {
  const drop = $("#drop");
  for (const name of ["dragenter", "dragover"]) {
    drop.addEventListener(name, (event) => { event.preventDefault(); drop.classList.add("over"); });
  }
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (event) => {
    event.preventDefault();
    drop.classList.remove("over");
    const files = [...(event.dataTransfer ? event.dataTransfer.files : [])];
    if (files.length) predictFiles(files);
    else showError("Nothing to read in what was dropped: drop image files.");
  });
  $("#files").addEventListener("change", (event) => {
    predictFiles([...event.target.files]);
    event.target.value = "";
  });
}

// --- the webcam through the stream -----------------------------------------------------

function streamUrl() {
  const url = new URL(`v1/stream?${predictParams()}`, window.location.href);
  url.protocol = url.protocol === "https:" ? "wss:" : "ws:";
  url.searchParams.set("smooth", $("#smooth").value);
  return url.toString();
}

async function startCamera() {
  showError("");
  const video = $("#video");
  let media;
  try {
    media = await navigator.mediaDevices.getUserMedia({ video: { width: 640, height: 480 }, audio: false });
  } catch (err) {
    showError(explain("camera", err && err.message ? err.message : String(err)));
    return;
  }
  video.srcObject = media;
  await video.play();
  const cam = { media, video, ws: null, inFlight: 0, answers: [], card: newResultCard("webcam"),
    canvas: document.createElement("canvas"), running: true };
  state.camera = cam;
  $("#live").hidden = false;
  $("#live-result").replaceChildren(cam.card);
  $("#camera").textContent = "Stop the webcam";
  openStream(cam);
}

function openStream(cam) {
  const ws = new WebSocket(streamUrl());
  ws.binaryType = "arraybuffer";
  cam.ws = ws;
  ws.addEventListener("open", () => {
    const key = apiKey();
    if (key) ws.send(JSON.stringify({ api_key: key }));
  });
  ws.addEventListener("message", (event) => onStreamMessage(cam, JSON.parse(event.data)));
  ws.addEventListener("close", (event) => {
    if (cam.running && !cam.refused) {
      showError(explain("network", `the stream closed (code ${event.code}${event.reason ? ": " + event.reason : ""})`));
    }
    stopCamera();
  });
}

function onStreamMessage(cam, message) {
  if (message.event === "ready") {
    $("#camera-status").textContent = `Streaming to ${message.model}, mode ${message.mode}.`;
    sendFrames(cam);
    return;
  }
  if (message.error && message.seq === undefined) {  // the stream was refused
    cam.refused = true;
    showError(explain(message.error.code, message.error.message));
    return;
  }
  cam.inFlight = Math.max(0, cam.inFlight - 1 - (message.dropped || 0));
  if (message.error) {
    showResultError(cam.card, explain(message.error.code, message.error.message));
    return;
  }
  cam.answers.push(performance.now());
  cam.answers = cam.answers.filter((t) => t > performance.now() - 2000);
  $("#fps").textContent = `${(cam.answers.length / 2).toFixed(1)} frames/s`;
  showAnswer(cam.card, message);
  drawView($(".view", cam.card), cam.canvas, cam.canvas.width, cam.canvas.height, message);
  showPose(cam.card, message);
}

// At most two frames wait for an answer (the server drops older ones anyway).
function sendFrames(cam) {
  if (!cam.running) return;
  const { video, canvas, ws } = cam;
  if (cam.inFlight < 2 && video.videoWidth && ws.readyState === WebSocket.OPEN) {
    canvas.width = video.videoWidth;
    canvas.height = video.videoHeight;
    canvas.getContext("2d").drawImage(video, 0, 0);
    cam.inFlight += 1;
    canvas.toBlob((blob) => { if (blob && ws.readyState === WebSocket.OPEN) ws.send(blob); },
      "image/jpeg", 0.85);
  }
  requestAnimationFrame(() => sendFrames(cam));
}

function stopCamera() {
  const cam = state.camera;
  if (!cam) return;
  cam.running = false;
  state.camera = null;
  for (const track of cam.media.getTracks()) track.stop();
  if (cam.ws && cam.ws.readyState <= WebSocket.OPEN) cam.ws.close(1000);
  $("#camera").textContent = "Start the webcam";
}

function setUpCamera() {
  $("#camera").addEventListener("click", () => (state.camera ? stopCamera() : startCamera()));
  const smooth = $("#smooth");
  smooth.addEventListener("input", () => {
    $("#smooth-value").textContent = Number(smooth.value) ? smooth.value : "off";
  });
  if (!navigator.mediaDevices || !navigator.mediaDevices.getUserMedia) {
    $("#camera").disabled = true;
    $("#camera-status").textContent = "This browser gives no webcam here (it needs https or localhost).";
  }
}

// A module runs once the document is parsed, as a deferred script would.
setUpDrop();
setUpCamera();
setUpFocal();
$("#api-key").addEventListener("change", () => { loadModels().then(loadPicture); loadCard(); loadCameras(); });
$("#model-name").addEventListener("change", () => { loadCard(); loadPicture(); });
loadModels().then(loadPicture);
loadCard();
loadCameras();
