// The frame viewer of `fusiondet view`: reads the frame embedded in #frame-data (written by
// crates/viz/src/web) and draws it with three.js (window.FusionThree). Coordinates are
// KITTI's LiDAR frame: x forward, y left, z up, metres.
"use strict";
(() => {
  const T = window.FusionThree;
  const data = JSON.parse(document.getElementById("frame-data").textContent);
  const $ = (id) => document.getElementById(id);

  // ---- decoding: points are int16 little-endian at `scale` metres, base64 ----
  function bytes(base64) {
    const text = atob(base64);
    const out = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) out[i] = text.charCodeAt(i);
    return out;
  }
  function positions(cloud) {
    const raw = bytes(cloud.xyz);
    const view = new DataView(raw.buffer);
    const out = new Float32Array(cloud.count * 3);
    for (let i = 0; i < out.length; i++) out[i] = view.getInt16(2 * i, true) * cloud.scale;
    return out;
  }

  // ---- colour ramps (the PNG pictures' height ramp: blue low, red high) ----
  const RAMP = [[0.16, 0.29, 0.85], [0.12, 0.75, 0.85], [0.35, 0.85, 0.3], [0.95, 0.85, 0.2], [0.9, 0.25, 0.2]];
  function ramp(t) {
    t = Math.min(1, Math.max(0, t)) * (RAMP.length - 1);
    const i = Math.min(RAMP.length - 2, Math.floor(t));
    const f = t - i;
    return RAMP[i].map((c, k) => c + (RAMP[i + 1][k] - c) * f);
  }
  const COLOUR_MODES = {
    height: (x, y, z) => ramp((z + 2.5) / 4.0),
    distance: (x, y, z) => ramp(Math.hypot(x, y) / 80.0),
    intensity: (x, y, z, r) => ramp(r),
  };

  // ---- the scene ----
  // In probe mode the layout has a fixed height, so that a screenshot and a DOM dump (two
  // browser runs, whose windows may differ in height) place everything alike.
  const probing = window.location.hash.includes("probe");
  if (probing) document.body.classList.add("probe");
  const pane = $("scene-pane");
  const scene = new T.Scene();
  scene.background = new T.Color(0x111318);
  const camera = new T.PerspectiveCamera(50, 1, 0.1, 2000);
  camera.up.set(0, 0, 1);
  const renderer = new T.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  pane.appendChild(renderer.domElement);
  const controls = new T.OrbitControls(camera, renderer.domElement);
  controls.addEventListener("change", render);
  const layers = {};

  function addLayer(name, object) {
    (layers[name] = layers[name] || []).push(object);
    scene.add(object);
  }

  let lidar = null;
  if (data.lidar) {
    const pos = positions(data.lidar);
    const intensity = bytes(data.lidar.intensity);
    const geometry = new T.BufferGeometry();
    geometry.setAttribute("position", new T.BufferAttribute(pos, 3));
    geometry.setAttribute("color", new T.BufferAttribute(new Float32Array(pos.length), 3));
    const material = new T.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true });
    lidar = { geometry, material, pos, intensity };
    addLayer("lidar", new T.Points(geometry, material));
  }
  // Colours are chosen in sRGB, as on screen; three.js works in linear RGB and encodes
  // back to sRGB when it draws, so each is converted on the way in.
  const linear = new T.Color();
  function setSrgb(attribute, i, r, g, b) {
    linear.setRGB(r, g, b, "srgb");
    attribute.setXYZ(i, linear.r, linear.g, linear.b);
  }
  function colourLidar(mode) {
    if (!lidar) return;
    const colour = lidar.geometry.getAttribute("color");
    const f = COLOUR_MODES[mode];
    lidar.srgb = new Float32Array(lidar.pos.length);
    for (let i = 0; i < data.lidar.count; i++) {
      const p = lidar.pos;
      const c = f(p[3 * i], p[3 * i + 1], p[3 * i + 2], lidar.intensity[i] / 255);
      lidar.srgb.set(c, 3 * i);
      setSrgb(colour, i, c[0], c[1], c[2]);
    }
    colour.needsUpdate = true;
  }

  let pseudo = null;
  if (data.pseudo) {
    const geometry = new T.BufferGeometry();
    geometry.setAttribute("position", new T.BufferAttribute(positions(data.pseudo), 3));
    const rgb = bytes(data.pseudo.rgb);
    const colour = new T.BufferAttribute(new Float32Array(rgb.length), 3);
    for (let i = 0; i < data.pseudo.count; i++) {
      setSrgb(colour, i, rgb[3 * i] / 255, rgb[3 * i + 1] / 255, rgb[3 * i + 2] / 255);
    }
    geometry.setAttribute("color", colour);
    const material = new T.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true });
    pseudo = { material };
    addLayer("pseudo", new T.Points(geometry, material));
  }

  // Box edges: bottom face 0-3, top face 4-7, verticals; then the heading mark.
  const EDGES = [0, 1, 1, 2, 2, 3, 3, 0, 4, 5, 5, 6, 6, 7, 7, 4, 0, 4, 1, 5, 2, 6, 3, 7];
  const FACES = [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
    1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6, 3, 0, 4, 3, 4, 7];
  const pickable = [];
  const boxes = data.boxes.map((b, index) => {
    const colour = new T.Color(data.colours[b.kind]);
    const c = b.corners;
    const lines = [];
    for (const k of EDGES) lines.push(c[3 * k], c[3 * k + 1], c[3 * k + 2]);
    lines.push(...b.centre, ...b.front);
    const edgeGeometry = new T.BufferGeometry();
    edgeGeometry.setAttribute("position", new T.Float32BufferAttribute(lines, 3));
    // Lines are drawn over the points (no depth test): a box is never hidden in its cloud.
    const edges = new T.LineSegments(edgeGeometry, new T.LineBasicMaterial({ color: colour, depthTest: false }));
    edges.renderOrder = 2;
    const faceGeometry = new T.BufferGeometry();
    faceGeometry.setAttribute("position", new T.Float32BufferAttribute(c, 3));
    faceGeometry.setIndex(FACES);
    const fill = new T.Mesh(faceGeometry, new T.MeshBasicMaterial({
      color: colour, transparent: true, opacity: 0.12, depthWrite: false, side: T.DoubleSide,
    }));
    fill.userData.box = index;
    pickable.push(fill);
    addLayer(b.kind, edges);
    addLayer(b.kind, fill);
    return { ...b, edges, fill };
  });

  if (data.frustum) {
    const o = data.frustum.origin;
    const f = data.frustum.far;
    const lines = [];
    for (let i = 0; i < 4; i++) lines.push(...o, ...f[i], ...f[i], ...f[(i + 1) % 4]);
    const geometry = new T.BufferGeometry();
    geometry.setAttribute("position", new T.Float32BufferAttribute(lines, 3));
    addLayer("frustum", new T.LineSegments(geometry, new T.LineBasicMaterial({ color: 0x6b7280 })));
  }

  // ---- state: layers, score threshold, point size, colour mode ----
  const state = { threshold: data.score_threshold, on: {} };
  for (const input of document.querySelectorAll("[data-layer]")) {
    const name = input.dataset.layer;
    const present = name === "dontcare" ? data.dontcare.length > 0 : !!layers[name];
    input.disabled = !present;
    if (!present) input.parentElement.style.opacity = 0.4;
    state.on[name] = input.checked;
    input.addEventListener("change", () => { state.on[name] = input.checked; update(); });
  }
  const score = $("score");
  const [lo, hi] = data.score_range;
  score.min = lo;
  score.max = hi;
  score.step = (hi - lo) / 100 || 0.01;
  score.value = state.threshold;
  score.disabled = !data.boxes.some((b) => b.kind === "det");
  score.addEventListener("input", () => { state.threshold = Number(score.value); update(); });
  $("point-size").addEventListener("input", (e) => setPointSize(Number(e.target.value)));
  $("colour-by").addEventListener("change", (e) => { colourLidar(e.target.value); render(); });

  function shown(b) {
    return state.on[b.kind] && (b.kind !== "det" || b.score === null || b.score >= state.threshold);
  }
  function setPointSize(size) {
    $("point-size").value = size;
    for (const cloud of [lidar, pseudo]) if (cloud) cloud.material.size = size;
    render();
  }
  function update() {
    for (const name of ["lidar", "pseudo", "frustum"]) {
      for (const o of layers[name] || []) o.visible = !!state.on[name];
    }
    for (const b of boxes) b.edges.visible = b.fill.visible = shown(b);
    $("score-value").textContent = state.threshold.toFixed(2);
    drawImage();
    render();
  }

  // ---- the camera image with the boxes' projected edges (computed in Rust, clipped) ----
  const img = $("camera-image");
  const overlay = $("image-overlay");
  overlay.width = data.image.width;
  overlay.height = data.image.height;
  img.src = "data:image/jpeg;base64," + data.image.jpeg;
  let hovered = null;
  function drawImage() {
    const g = overlay.getContext("2d");
    g.clearRect(0, 0, overlay.width, overlay.height);
    if (state.on.dontcare) {
      g.setLineDash([6, 4]);
      g.strokeStyle = data.colours.dontcare;
      g.lineWidth = 1.5;
      for (const [x1, y1, x2, y2] of data.dontcare) g.strokeRect(x1, y1, x2 - x1, y2 - y1);
      g.setLineDash([]);
    }
    boxes.forEach((b, i) => {
      if (!shown(b)) return;
      g.strokeStyle = data.colours[b.kind];
      g.lineWidth = i === hovered ? 4 : 2;
      g.beginPath();
      const s = b.image;
      for (let k = 0; k + 3 < s.length; k += 4) {
        g.moveTo(s[k], s[k + 1]);
        g.lineTo(s[k + 2], s[k + 3]);
      }
      g.stroke();
    });
  }

  // ---- legend, hover details ----
  const counts = { gt: 0, det: 0 };
  for (const b of data.boxes) counts[b.kind]++;
  $("legend").innerHTML = [["gt", "ground truth"], ["det", "detections"], ["dontcare", "DontCare (image)"]]
    .map(([k, label]) => `<span><i style="background:${data.colours[k]}"></i>${label}` +
      (k === "dontcare" ? ` ${data.dontcare.length}` : ` ${counts[k]}`) + "</span>")
    .join("") + (data.lidar ? `<span>${data.lidar.count.toLocaleString()} LiDAR points</span>` : "") +
    (data.pseudo ? `<span>${data.pseudo.count.toLocaleString()} pseudo points</span>` : "");

  function describe(b) {
    const head = `${b.kind === "gt" ? "ground truth" : "detection"}: ${b.class}` +
      (b.score !== null ? `  score ${b.score.toFixed(3)}` : "");
    const size = `l ${b.size[0].toFixed(2)}  w ${b.size[1].toFixed(2)}  h ${b.size[2].toFixed(2)} m`;
    const where = `${b.distance.toFixed(1)} m away`;
    const label = b.kind === "gt" ? `\noccluded ${b.occluded}  truncated ${b.truncated.toFixed(2)}` : "";
    return `${head}\n${size}\n${where}${label}`;
  }
  const raycaster = new T.Raycaster();
  const tooltip = $("tooltip");
  renderer.domElement.addEventListener("pointermove", (e) => {
    const r = renderer.domElement.getBoundingClientRect();
    const ndc = new T.Vector2(((e.clientX - r.left) / r.width) * 2 - 1, -((e.clientY - r.top) / r.height) * 2 + 1);
    raycaster.setFromCamera(ndc, camera);
    const hit = raycaster.intersectObjects(pickable.filter((m) => m.visible))[0];
    const next = hit ? hit.object.userData.box : null;
    if (next !== null) {
      tooltip.hidden = false;
      tooltip.textContent = describe(boxes[next]);
      tooltip.style.left = `${e.clientX - r.left + 14}px`;
      tooltip.style.top = `${e.clientY - r.top + 10}px`;
      $("details").textContent = describe(boxes[next]);
    } else {
      tooltip.hidden = true;
    }
    if (next !== hovered) { hovered = next; drawImage(); }
  });

  // ---- views ----
  function resetView() {
    camera.position.set(-12, 0, 10);
    controls.target.set(18, 0, 0);
    controls.update();
  }
  function birdsEye() {
    // Straight down, forward (x) up on screen: the camera sits a hair behind its target.
    controls.target.set(35, 0, 0);
    camera.position.set(34.999, 0, 95);
    controls.update();
  }
  $("bev").addEventListener("click", birdsEye);
  $("reset").addEventListener("click", resetView);
  $("help-button").addEventListener("click", () => { $("help").hidden = !$("help").hidden; });

  // ---- keys ----
  const LAYER_KEYS = ["lidar", "pseudo", "gt", "det", "dontcare", "frustum"];
  function go(link) { if (link) window.location.href = link; }
  window.addEventListener("keydown", (e) => {
    if (e.target.tagName === "SELECT" || e.ctrlKey || e.metaKey || e.altKey) return;
    const k = e.key;
    if (k === "b") birdsEye();
    else if (k === "r") resetView();
    else if (k === "c") {
      const select = $("colour-by");
      select.selectedIndex = (select.selectedIndex + 1) % select.options.length;
      select.dispatchEvent(new Event("change"));
    } else if (k === "+" || k === "=") setPointSize(Math.min(8, Number($("point-size").value) + 0.5));
    else if (k === "-") setPointSize(Math.max(1, Number($("point-size").value) - 0.5));
    else if (k === "[" || k === "]") {
      const step = Number(score.step) * 5 * (k === "]" ? 1 : -1);
      score.value = Math.min(Number(score.max), Math.max(Number(score.min), Number(score.value) + step));
      score.dispatchEvent(new Event("input"));
    } else if (k >= "1" && k <= "6") {
      const input = document.querySelector(`[data-layer=${LAYER_KEYS[Number(k) - 1]}]`);
      if (!input.disabled) { input.checked = !input.checked; input.dispatchEvent(new Event("change")); }
    } else if (k === "ArrowLeft" || k === "p") go(data.nav.prev);
    else if (k === "ArrowRight" || k === "n") go(data.nav.next);
    else if (k === "i") go(data.nav.index);
    else if (k === "?") $("help").hidden = !$("help").hidden;
  });

  // ---- drawing ----
  function resize() {
    const w = pane.clientWidth, h = pane.clientHeight;
    renderer.setSize(w, h);
    camera.aspect = w / Math.max(1, h);
    camera.updateProjectionMatrix();
    render();
  }
  function render() {
    renderer.render(scene, camera);
  }
  window.addEventListener("resize", resize);
  colourLidar("height");
  resetView();
  resize();
  update();

  // ---- probe (#probe in the address): where things landed on the page, for the browser
  // test, which compares these positions with the pixels of a screenshot ----
  function probe() {
    const r = renderer.domElement.getBoundingClientRect();
    const toPage = (x, y, z) => {
      const v = new T.Vector3(x, y, z).project(camera);
      return [r.left + (v.x + 1) / 2 * r.width, r.top + (1 - v.y) / 2 * r.height, v.z];
    };
    const inView = ([x, y, z]) => z < 1 && x > r.left + 2 && x < r.right - 2 && y > r.top + 2 && y < r.bottom - 2;
    const edgeMidpoints = (b) => {
      const out = [];
      for (let e = 0; e < EDGES.length; e += 2) {
        const [a, c] = [EDGES[e], EDGES[e + 1]];
        const m = [0, 1, 2].map((k) => (b.corners[3 * a + k] + b.corners[3 * c + k]) / 2);
        const p = toPage(...m);
        if (inView(p)) out.push([p[0], p[1]]);
      }
      return out;
    };
    const ir = overlay.getBoundingClientRect();
    const sx = ir.width / data.image.width, sy = ir.height / data.image.height;
    const boxesOut = boxes.filter(shown).map((b) => ({
      kind: b.kind,
      colour: data.colours[b.kind],
      scene: edgeMidpoints(b),
      image: Array.from({ length: b.image.length / 4 }, (_, k) => [
        ir.left + (b.image[4 * k] + b.image[4 * k + 2]) / 2 * sx,
        ir.top + (b.image[4 * k + 1] + b.image[4 * k + 3]) / 2 * sy]),
    }));
    const points = [];
    if (lidar) {
      const stride = Math.max(1, Math.floor(data.lidar.count / 400));
      const c = lidar.srgb;
      for (let i = 0; i < data.lidar.count; i += stride) {
        const p = toPage(lidar.pos[3 * i], lidar.pos[3 * i + 1], lidar.pos[3 * i + 2]);
        if (inView(p)) points.push([p[0], p[1], c[3 * i], c[3 * i + 1], c[3 * i + 2]]);
      }
    }
    const out = $("probe");
    out.textContent = JSON.stringify({
      scene: [r.left, r.top, r.width, r.height], background: "#111318", boxes: boxesOut, points,
    });
  }
  function ready() {
    // `#bev` in the address opens the bird's-eye view.
    if (window.location.hash.includes("bev")) birdsEye();
    if (probing) probe();
    document.body.dataset.ready = "1";
  }
  // The image pane has its height once the image is decoded.
  if (img.complete) ready();
  else img.addEventListener("load", ready);
})();
