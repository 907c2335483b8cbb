/* qifreport HTML viewer: the deviation map of one inspection (qifreport/reports/html.py).

   Draws with three.js (the global THREE, with THREE.TrackballControls) the JSON of the
   page's "viewer-data" script element: typed arrays in base64 (little-endian), lengths in mm.
   Sets <body data-status> to "drawn" once the map is drawn, or "error" (with the reason
   shown) when it cannot be. */
(function () {
  "use strict";

  const body = document.body;
  const view = document.getElementById("view");
  const msg = document.getElementById("msg");
  const readout = document.getElementById("readout");

  function fail(text) {
    body.dataset.status = "error";
    msg.textContent = text;
    msg.hidden = false;
  }

  if (typeof THREE === "undefined" || !THREE.TrackballControls) {
    fail("three.js did not load: the deviation map cannot be drawn.");
    return;
  }
  const D = JSON.parse(document.getElementById("viewer-data").textContent);
  const rev = document.getElementById("three-rev");
  if (rev) rev.textContent = "r" + THREE.REVISION;

  // ------------------------------------------------------------------------ decoding
  const TYPES = {
    u8: Uint8Array, u16: Uint16Array, u32: Uint32Array,
    i16: Int16Array, i32: Int32Array, f32: Float32Array,
  };

  function typed(a) {
    if (!a) return null;
    const bin = atob(a.data);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new TYPES[a.dtype](bytes.buffer);
  }

  /* uint16 positions on the frame's grid -> Float32Array, mm */
  function positions(a) {
    const q = typed(a);
    const o = D.frame.origin;
    const s = D.frame.step;
    const out = new Float32Array(q.length);
    for (let i = 0; i < q.length; i += 3) {
      out[i] = o[0] + s[0] * q[i];
      out[i + 1] = o[1] + s[1] * q[i + 1];
      out[i + 2] = o[2] + s[2] * q[i + 2];
    }
    return out;
  }

  // ---------------------------------------------------------------------- the scene
  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  } catch (e) {
    fail("This browser cannot draw WebGL here (" + e.message + "); open the file in a " +
      "browser with WebGL enabled.");
    return;
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(0xffffff, 1);
  renderer.setSize(view.clientWidth, view.clientHeight);
  view.insertBefore(renderer.domElement, view.firstChild);
  const canvas = renderer.domElement;

  const scene = new THREE.Scene();
  const V = positions(D.positions);
  const dev = typed(D.deviation);
  const governing = typed(D.governing);
  const position = new THREE.BufferAttribute(V, 3);
  const color = new THREE.BufferAttribute(typed(D.colors), 3, true);

  // normals over every triangle (the zones' groups share the vertices)
  const indices = D.zones.map((z) => typed(z.index));
  const faces = D.zones.map((z) => typed(z.faces));
  const total = indices.reduce((n, ix) => n + ix.length, 0);
  const all = new (D.n_vertices > 65536 ? Uint32Array : Uint16Array)(total);
  let at = 0;
  for (const ix of indices) { all.set(ix, at); at += ix.length; }
  const whole = new THREE.BufferGeometry();
  whole.setAttribute("position", position);
  whole.setIndex(new THREE.BufferAttribute(all, 1));
  whole.computeVertexNormals();
  const normal = whole.getAttribute("normal");

  const surfaceMaterial = new THREE.MeshLambertMaterial({
    vertexColors: true,
    side: THREE.DoubleSide,
    polygonOffset: true,
    polygonOffsetFactor: 1,
    polygonOffsetUnits: 1,
  });
  const surfaces = indices.map((ix, k) => {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", position);
    g.setAttribute("normal", normal);
    g.setAttribute("color", color);
    g.setIndex(new THREE.BufferAttribute(ix, 1));
    g.computeBoundingSphere();
    const m = new THREE.Mesh(g, surfaceMaterial);
    m.userData.zone = k;
    scene.add(m);
    return m;
  });

  scene.add(new THREE.AmbientLight(0xffffff, 0.35));
  const headlight = new THREE.DirectionalLight(0xffffff, 0.65);
  scene.add(headlight);
  scene.add(headlight.target);

  let outline = null;
  if (D.outline) {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(positions(D.outline), 3));
    outline = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: D.outline_color }));
    scene.add(outline);
  }

  const pg = new THREE.BufferGeometry();
  pg.setAttribute("position", new THREE.BufferAttribute(positions(D.points.positions), 3));
  const points = new THREE.Points(
    pg, new THREE.PointsMaterial({ color: 0x2a3140, size: 2, sizeAttenuation: false }));
  points.visible = false;
  scene.add(points);

  const R = D.radius;
  const markers = new THREE.Group();
  for (const m of D.markers) {
    const s = new THREE.Mesh(new THREE.SphereGeometry(0.012 * R, 16, 12),
      new THREE.MeshBasicMaterial({ color: 0x141414 }));
    s.position.set(m.position[0], m.position[1], m.position[2]);
    markers.add(s);
  }
  scene.add(markers);

  const picked = new THREE.Mesh(new THREE.SphereGeometry(0.008 * R, 12, 8),
    new THREE.MeshBasicMaterial({ color: 0x000000, depthTest: false }));
  picked.renderOrder = 10;
  picked.visible = false;
  scene.add(picked);

  // region of each vertex (0: none), the regions' numbers as in the PDF
  const regionOf = new Uint16Array(D.n_vertices);
  for (const r of D.regions) {
    for (const v of typed(r.vertices)) if (!regionOf[v]) regionOf[v] = r.number;
  }

  // ------------------------------------------------------------- labels over the map
  const labels = document.getElementById("labels");
  const anchors = [];
  function addLabel(cls, html, p) {
    const el = document.createElement("div");
    el.className = cls;
    el.innerHTML = html;
    labels.appendChild(el);
    anchors.push({ el: el, p: new THREE.Vector3(p[0], p[1], p[2]), cls: cls });
  }
  for (const r of D.regions) {
    addLabel("rlabel", '<span class="dot"></span><span class="num">' + r.number + "</span>",
      r.anchor);
  }
  for (const m of D.markers) {
    const el = document.createElement("span");
    el.textContent = m.name;
    addLabel("mlabel", el.outerHTML, m.position);
  }

  // ------------------------------------------------------------------------- camera
  const camera = new THREE.OrthographicCamera(-1, 1, 1, -1, 0.05 * R, 10 * R);
  const controls = new THREE.TrackballControls(camera, canvas);
  controls.rotateSpeed = 3.0;
  controls.zoomSpeed = 1.2;
  controls.panSpeed = 0.8;
  controls.staticMoving = true;
  // the half extents (mm) the view must show, whatever the window's shape (zooming with the
  // mouse changes camera.zoom, not these)
  let fitWidth = 1;
  let fitHeight = 1;

  function aspect() { return Math.max(canvas.clientWidth, 1) / Math.max(canvas.clientHeight, 1); }

  function frustum() {
    const a = aspect();
    const halfHeight = Math.max(fitHeight, fitWidth / a);
    camera.left = -halfHeight * a;
    camera.right = halfHeight * a;
    camera.top = halfHeight;
    camera.bottom = -halfHeight;
    camera.updateProjectionMatrix();
  }

  /* the PDF's view k: its direction and up, the part fitted with a 6 % margin */
  function setView(k) {
    const v = D.views[k];
    if (!v) return;
    const c = new THREE.Vector3(v.center[0], v.center[1], v.center[2]);
    const d = new THREE.Vector3(v.direction[0], v.direction[1], v.direction[2]);
    fitWidth = 1.06 * v.half_width;
    fitHeight = 1.06 * v.half_height;
    camera.position.copy(c).addScaledVector(d, 4 * R);
    camera.up.set(v.up[0], v.up[1], v.up[2]);
    camera.zoom = 1;
    controls.target.copy(c);
    camera.lookAt(c);
    frustum();
    dirty = true;
  }

  // ------------------------------------------------------------------------- drawing
  let dirty = true;
  const p = new THREE.Vector3();

  function placeLabels() {
    const w = canvas.clientWidth;
    const h = canvas.clientHeight;
    for (const a of anchors) {
      p.copy(a.p).project(camera);
      const x = (p.x + 1) / 2 * w;
      const y = (1 - p.y) / 2 * h;
      const inside = x >= 0 && x <= w && y >= 0 && y <= h;
      a.el.style.display = inside ? "" : "none";
      a.el.style.transform = "translate(" + x.toFixed(1) + "px," + y.toFixed(1) + "px)";
    }
  }

  function draw() {
    headlight.position.copy(camera.position);
    headlight.target.position.copy(controls.target);
    renderer.render(scene, camera);
    placeLabels();
    dirty = false;
    body.dataset.status = "drawn";
  }

  controls.addEventListener("change", () => { dirty = true; });

  function frame() {
    requestAnimationFrame(frame);
    controls.update();
    if (dirty) draw();
  }

  window.addEventListener("resize", () => {
    renderer.setSize(view.clientWidth, view.clientHeight);
    frustum();
    controls.handleResize();
    dirty = true;
  });

  // ------------------------------------------------------------------------ readout
  const raycaster = new THREE.Raycaster();
  const ndc = new THREE.Vector2();

  function mm(x) { return (x >= 0 ? "+" : "\u2212") + Math.abs(x).toFixed(3); }
  function band(z) {
    return "[" + mm(z[0]) + ", " + mm(z[1]) + "] mm";
  }
  function esc(s) {
    return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;",
      '"': "&quot;" })[c]);
  }

  function faceText(zone, tri) {
    const f = faces[zone];
    if (!f) return "\u2014 (a mesh nominal has no B-rep faces)";
    const id = f[tri];
    const sid = D.face_step_ids ? D.face_step_ids[id] : -1;
    return "B-rep face " + id + (sid >= 0 ? " (STEP #" + sid + ")" : "");
  }

  /* the readout of vertex v, hit on triangle tri of the zone group zone */
  function show(v, zone, tri) {
    const d = dev[v];
    const g = governing[v];
    const z = g >= 0 ? D.zones[g] : null;
    const lims = z && z.lower !== null ? [z.lower, z.upper] : D.default_band;
    const rows = [];
    let cls = "";
    let state = "not scored (not observed by the scan, or in an unscored band)";
    if (Number.isFinite(d)) {
      state = "in tolerance";
      if (lims && d > lims[1]) { state = "out of tolerance: proud"; cls = " out"; }
      if (lims && d < lims[0]) { state = "out of tolerance: sunk"; cls = " out"; }
    }
    rows.push('<div class="dev' + cls + '">' +
      (Number.isFinite(d) ? mm(d) + " mm" : "not scored") + "</div>");
    if (Number.isFinite(d)) rows.push("<div>" + state + "</div>");
    else rows.push('<div class="k">' + state + "</div>");
    const tol = z ? "<b>" + esc(z.key) + "</b> " + esc(z.label) :
      (lims ? "part band " + band(lims) : "\u2014");
    rows.push('<div><span class="k">tolerance</span> ' + tol + "</div>");
    rows.push('<div><span class="k">face</span> ' + esc(faceText(zone, tri)) + "</div>");
    if (regionOf[v]) {
      const r = D.regions[regionOf[v] - 1];
      rows.push('<div><span class="k">region</span> ' + r.number + " (" +
        r.area.toFixed(1) + " mm\u00b2, peak " + mm(r.peak) + " mm)</div>");
    }
    rows.push('<div><span class="k">at</span> (' + V[3 * v].toFixed(2) + ", " +
      V[3 * v + 1].toFixed(2) + ", " + V[3 * v + 2].toFixed(2) + ") mm, vertex " + v + "</div>");
    readout.innerHTML = rows.join("");
    readout.hidden = false;
    readout.dataset.vertex = String(v);
    readout.dataset.deviation = Number.isFinite(d) ? d.toPrecision(9) : "nan";
    readout.dataset.zone = z ? z.key : "";
    readout.dataset.face = faces[zone] ? String(faces[zone][tri]) : "";
    readout.dataset.region = String(regionOf[v]);
    picked.position.set(V[3 * v], V[3 * v + 1], V[3 * v + 2]);
    picked.visible = true;
    dirty = true;
  }

  /* pick what is drawn at client pixel (x, y) */
  function pickAt(x, y) {
    const rect = canvas.getBoundingClientRect();
    ndc.set((x - rect.left) / rect.width * 2 - 1, -((y - rect.top) / rect.height) * 2 + 1);
    pickNdc();
  }

  /* pick what is drawn where the point (x, y, z) mm projects */
  function pickPoint(x, y, z) {
    const q = new THREE.Vector3(x, y, z).project(camera);
    ndc.set(q.x, q.y);
    pickNdc();
  }

  function pickNdc() {
    raycaster.setFromCamera(ndc, camera);
    const hits = raycaster.intersectObjects(surfaces.filter((m) => m.visible), false);
    if (!hits.length) {
      readout.hidden = true;
      readout.dataset.vertex = "";
      picked.visible = false;
      dirty = true;
      return;
    }
    const h = hits[0];
    let best = h.face.a;
    let bestD = Infinity;
    for (const v of [h.face.a, h.face.b, h.face.c]) {
      const dx = V[3 * v] - h.point.x;
      const dy = V[3 * v + 1] - h.point.y;
      const dz = V[3 * v + 2] - h.point.z;
      const dd = dx * dx + dy * dy + dz * dz;
      if (dd < bestD) { bestD = dd; best = v; }
    }
    show(best, h.object.userData.zone, h.faceIndex);
  }

  let pending = null;
  canvas.addEventListener("pointermove", (e) => {
    if (e.buttons) return; // rotating, zooming or panning
    if (pending === null) {
      requestAnimationFrame(() => { const q = pending; pending = null; pickAt(q[0], q[1]); });
    }
    pending = [e.clientX, e.clientY];
  });
  canvas.addEventListener("click", (e) => pickAt(e.clientX, e.clientY));

  // ------------------------------------------------------------------------ toggles
  for (const box of document.querySelectorAll("input[data-layer]")) {
    box.addEventListener("change", () => {
      const on = box.checked;
      const layer = box.dataset.layer;
      if (layer === "zone") surfaces[Number(box.dataset.zone)].visible = on;
      else if (layer === "outline" && outline) outline.visible = on;
      else if (layer === "points") points.visible = on;
      else if (layer === "markers") {
        markers.visible = on;
        for (const a of anchors) if (a.cls === "mlabel") a.el.hidden = !on;
      } else if (layer === "labels") {
        for (const a of anchors) if (a.cls === "rlabel") a.el.hidden = !on;
      }
      dirty = true;
    });
  }
  for (const b of document.querySelectorAll("button[data-view]")) {
    b.addEventListener("click", () => setView(Number(b.dataset.view)));
  }
  window.addEventListener("keydown", (e) => {
    if ((e.key === "r" || e.key === "R") && !e.ctrlKey && !e.metaKey) setView(0);
  });

  // --------------------------------------------------------------------------- start
  setView(0);
  draw();
  // #at=X,Y,Z (mm, e.g. a region's centroid from the PDF or the QIF): pick the part there
  const num = "(-?[0-9.]+(?:e-?[0-9]+)?)";
  const m = new RegExp("at=" + num + "," + num + "," + num).exec(window.location.hash);
  if (m) {
    pickPoint(Number(m[1]), Number(m[2]), Number(m[3]));
    draw();
  }
  requestAnimationFrame(frame);
})();
