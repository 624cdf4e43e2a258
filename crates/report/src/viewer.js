// Handheld's report viewer: WebGL2, hand-written. Data: window.HANDHELD (report/scene.js).
// Orbit (drag), pan (shift/right drag), zoom (wheel), reset, layer toggles; a click on a camera
// shows its photo and views the scene through it. window.handheldStats says what was drawn.
// Text from data (camera names, thumbnail paths) goes into the page only through textContent and
// DOM properties, never through HTML strings; the page's Content-Security-Policy allows no
// inline handler, so the viewer's own handlers are attached here.
// The hash sets the view: #viewer (the viewer alone), camera=N (through camera N, as a click
// on it does), layers=mesh,points,cameras (the layers shown, through their toggles).
// Frames drawn while the view moves keep to a budget (FRAME_BUDGET_MS): software WebGL pays per
// pixel, so they are drawn into fewer backing pixels (a resolution scale adapted to the last
// frames' cost, never below MIN_SCALE) and stretched to the canvas, with one sparse point in
// POINT_STRIDE; once the view rests, the still frame is drawn at full resolution with every point.
(function () {
  "use strict";
  const status = document.getElementById("hh-status");
  const stats = { errors: [], points: 0, triangles: 0, cameras: 0, frames: 0, ms_per_frame: null, scale: 1, full_ms_per_frame: null, context_lost: false };
  const FRAME_BUDGET_MS = 25, MIN_SCALE = 0.4, REST_MS = 150;
  // While the view moves, one point in POINT_STRIDE is drawn (every point costs its own setup).
  const POINT_STRIDE = 4;
  window.handheldStats = stats;
  function report() { if (status) status.textContent = JSON.stringify(stats); }
  window.addEventListener("error", (e) => { stats.errors.push(String(e.message)); report(); });
  const origError = console.error;
  console.error = function () { stats.errors.push(Array.from(arguments).join(" ")); report(); origError.apply(console, arguments); };
  document.addEventListener("securitypolicyviolation", (e) => {
    stats.errors.push("Content-Security-Policy blocked " + (e.blockedURI || "inline code") + " (" + e.violatedDirective + ")"); report();
  });
  const viewerOnly = document.getElementById("hh-viewer-only");
  if (viewerOnly) viewerOnly.addEventListener("click", () => setTimeout(() => location.reload()));

  if (location.hash.startsWith("#viewer")) document.body.classList.add("viewer-only");
  const S = window.HANDHELD;
  const canvas = document.getElementById("hh-canvas");
  if (!S || !canvas) { stats.errors.push("no scene data"); report(); return; }
  const gl = canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: false, powerPreference: "high-performance" });
  if (!gl) { stats.errors.push("WebGL2 is not available"); report(); return; }
  canvas.addEventListener("webglcontextlost", (e) => {
    e.preventDefault(); stats.context_lost = true; stats.errors.push("WebGL context lost"); report();
  });
  canvas.addEventListener("webglcontextrestored", () => location.reload());

  function b64(s, T) {
    const bin = atob(s); const u8 = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) u8[i] = bin.charCodeAt(i);
    return new T(u8.buffer);
  }
  function shader(type, src) {
    const sh = gl.createShader(type); gl.shaderSource(sh, src); gl.compileShader(sh);
    if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(sh));
    return sh;
  }
  function program(vs, fs) {
    const p = gl.createProgram();
    gl.attachShader(p, shader(gl.VERTEX_SHADER, vs)); gl.attachShader(p, shader(gl.FRAGMENT_SHADER, fs));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    return p;
  }
  const colourProg = program(
    "#version 300 es\nin vec3 p; in vec3 c; uniform mat4 m; uniform float s; out vec3 vc;\n" +
    "void main(){ gl_Position = m * vec4(p, 1.0); gl_PointSize = s; vc = c; }",
    "#version 300 es\nprecision mediump float; in vec3 vc; out vec4 o; void main(){ o = vec4(vc, 1.0); }");
  const meshProg = program(
    "#version 300 es\nin vec3 p; in vec2 t; uniform mat4 m; out vec2 vt;\n" +
    "void main(){ gl_Position = m * vec4(p, 1.0); vt = t; }",
    "#version 300 es\nprecision mediump float; in vec2 vt; uniform sampler2D tex; out vec4 o;\n" +
    "void main(){ o = vec4(texture(tex, vt).rgb, 1.0); }");

  function buffer(data, target) {
    const b = gl.createBuffer(); gl.bindBuffer(target || gl.ARRAY_BUFFER, b);
    gl.bufferData(target || gl.ARRAY_BUFFER, data, gl.STATIC_DRAW); return b;
  }
  function vao(prog, attrs, index) {
    const v = gl.createVertexArray(); gl.bindVertexArray(v);
    for (const [name, buf, size, type, norm] of attrs) {
      const loc = gl.getAttribLocation(prog, name); if (loc < 0) continue;
      gl.bindBuffer(gl.ARRAY_BUFFER, buf); gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, size, type || gl.FLOAT, !!norm, 0, 0);
    }
    if (index) gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, index);
    gl.bindVertexArray(null); return v;
  }

  // Layers.
  const layers = {};
  if (S.points && S.points.count > 0) {
    const pos0 = b64(S.points.pos, Float32Array), col0 = b64(S.points.col, Uint8Array);
    // Reordered so that the first 1/POINT_STRIDE of the buffer is every POINT_STRIDE-th point.
    const n = S.points.count, pos = new Float32Array(3 * n), col = new Uint8Array(3 * n), order = [];
    for (let r = 0; r !== POINT_STRIDE; r++) for (let i = r; n > i; i += POINT_STRIDE) order.push(i);
    order.forEach((i, k) => { pos.set(pos0.subarray(3 * i, 3 * i + 3), 3 * k); col.set(col0.subarray(3 * i, 3 * i + 3), 3 * k); });
    layers.points = { vao: vao(colourProg, [["p", buffer(pos), 3], ["c", buffer(col), 3, gl.UNSIGNED_BYTE, true]]), count: n, on: true };
  }
  // Camera frusta as lines: centre to the four image corners at a depth, and the rectangle.
  const frusta = []; const fcol = [];
  const depth = S.frustum_depth;
  for (const c of S.cameras) {
    const R = c.r; // world_from_cam, row-major 3×3
    const corner = (u, v) => {
      const x = (u - c.cx) / c.f * depth, y = (v - c.cy) / (c.f * c.aspect) * depth, z = depth;
      return [c.c[0] + R[0] * x + R[1] * y + R[2] * z, c.c[1] + R[3] * x + R[4] * y + R[5] * z, c.c[2] + R[6] * x + R[7] * y + R[8] * z];
    };
    const k = [corner(0, 0), corner(c.w, 0), corner(c.w, c.h), corner(0, c.h)];
    const col = c.registered ? [0.95, 0.45, 0.1] : [0.6, 0.6, 0.6];
    for (let i = 0; i < 4; i++) { frusta.push(...c.c, ...k[i], ...k[i], ...k[(i + 1) % 4]); for (let j = 0; j < 4; j++) fcol.push(...col); }
  }
  if (frusta.length) {
    const colU8 = new Uint8Array(fcol.map((v) => Math.round(v * 255)));
    layers.cameras = { vao: vao(colourProg, [["p", buffer(new Float32Array(frusta)), 3], ["c", buffer(colU8), 3, gl.UNSIGNED_BYTE, true]]), count: frusta.length / 3, on: true };
  }
  // The frame cost is measured once the scene is complete: after the atlas, when there is one.
  let atlasLoaded = null;
  if (S.mesh && S.mesh.faces > 0) {
    const pos = b64(S.mesh.pos, Float32Array), uv = b64(S.mesh.uv, Float32Array), idx = b64(S.mesh.idx, Uint32Array);
    const tex = gl.createTexture(); gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB, 1, 1, 0, gl.RGB, gl.UNSIGNED_BYTE, new Uint8Array([180, 180, 180]));
    const m = { vao: vao(meshProg, [["p", buffer(pos), 3], ["t", buffer(uv), 2]], buffer(idx, gl.ELEMENT_ARRAY_BUFFER)), count: idx.length, tex: tex, on: true };
    layers.mesh = m;
    if (S.mesh.atlas) {
      atlasLoaded = new Promise((done) => {
        const img = new Image();
        img.onload = () => {
          gl.bindTexture(gl.TEXTURE_2D, tex);
          gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB, gl.RGB, gl.UNSIGNED_BYTE, img);
          gl.generateMipmap(gl.TEXTURE_2D);
          gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR_MIPMAP_LINEAR);
          draw();
          done();
        };
        img.onerror = () => done();
        img.src = S.mesh.atlas;
      });
    }
  }

  // View: orbit around a target; or through a recorded camera.
  const view = { target: S.center.slice(), dist: S.radius * 2.2, yaw: 0.6, pitch: 0.35, through: null };
  const up = S.up; // the cameras' mean up direction
  // An orthonormal frame with `up` as its third axis.
  const ax = (() => {
    let a = Math.abs(up[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0];
    const d = a[0] * up[0] + a[1] * up[1] + a[2] * up[2];
    a = [a[0] - d * up[0], a[1] - d * up[1], a[2] - d * up[2]];
    const n = Math.hypot(...a); a = a.map((v) => v / n);
    const b = [up[1] * a[2] - up[2] * a[1], up[2] * a[0] - up[0] * a[2], up[0] * a[1] - up[1] * a[0]];
    return [a, b];
  })();
  // Start behind the cameras' mean position, looking at the scene's centre, so that the model
  // and the cameras are both in view.
  function home() {
    view.target = S.center.slice(); view.through = null; view.yaw = 0.6; view.pitch = 0.35; view.dist = S.radius * 2.2;
    if (S.cameras.length) {
      const off = S.cameras.map((c) => [0, 1, 2].map((i) => c.c[i] - view.target[i]));
      const dists = off.map((d) => Math.hypot(...d)).sort((a, b) => a - b);
      const med = dists[dists.length >> 1];
      let d = [0, 1, 2].map((i) => off.reduce((a, o) => a + o[i], 0) / off.length);
      // Cameras all around the scene (a ring): look from the first camera's side instead.
      if (Math.hypot(...d) < 0.3 * med) d = off[0];
      const len = Math.hypot(...d);
      if (len > 1e-9 && med > 0) {
        const u = d.map((v) => v / len);
        const along = (a) => a[0] * u[0] + a[1] * u[1] + a[2] * u[2];
        view.pitch = Math.max(-1.2, Math.min(1.2, Math.asin(Math.max(-1, Math.min(1, along(up)))) + 0.3));
        view.yaw = Math.atan2(along(ax[1]), along(ax[0]));
        view.dist = med * 1.5;
      }
    }
  }
  function reset() { home(); draw(); }
  home();

  function matMul(a, b) { const o = new Float32Array(16); for (let i = 0; i < 4; i++) for (let j = 0; j < 4; j++) { let s = 0; for (let k = 0; k < 4; k++) s += a[k * 4 + j] * b[i * 4 + k]; o[i * 4 + j] = s; } return o; }
  function perspective(fovy, aspect, near, far) {
    const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
  }
  // Column-major view matrix from a camera-to-world rotation (columns x right, y up, z back) and eye.
  function viewMatrix(x, y, z, e) {
    const d = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -d(x, e), -d(y, e), -d(z, e), 1]);
  }
  function eyeFrame() {
    if (view.through !== null) {
      const c = S.cameras[view.through], R = c.r;
      // Handheld camera: x right, y down, z forward → GL: x, −y, −z.
      const x = [R[0], R[3], R[6]], y = [-R[1], -R[4], -R[7]], z = [-R[2], -R[5], -R[8]];
      return { x, y, z, e: c.c, fovy: 2 * Math.atan(c.h / 2 / (c.f * c.aspect)) };
    }
    const cp = Math.cos(view.pitch), sp = Math.sin(view.pitch), cy = Math.cos(view.yaw), sy = Math.sin(view.yaw);
    const dir = [0, 1, 2].map((i) => ax[0][i] * cp * cy + ax[1][i] * cp * sy + up[i] * sp);
    const e = [0, 1, 2].map((i) => view.target[i] + dir[i] * view.dist);
    const z = dir;
    let x = [up[1] * z[2] - up[2] * z[1], up[2] * z[0] - up[0] * z[2], up[0] * z[1] - up[1] * z[0]];
    const n = Math.hypot(...x) || 1; x = x.map((v) => v / n);
    const y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]];
    return { x, y, z, e, fovy: 0.8 };
  }
  let mvp = null;
  // Resolution scale of the frames drawn while the view moves, and whether the view is moving.
  let moving = false, scale = 1, restTimer = 0;
  function draw() {
    const k = moving ? scale : 1;
    const w = Math.max(1, Math.round(canvas.clientWidth * k)), h = Math.max(1, Math.round(canvas.clientHeight * k));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(0.13, 0.14, 0.16, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    const f = eyeFrame();
    const near = Math.max(S.radius * 1e-3, 1e-6), far = S.radius * 100 + view.dist * 4;
    mvp = matMul(perspective(f.fovy, canvas.width / Math.max(1, canvas.height), near, far), viewMatrix(f.x, f.y, f.z, f.e));
    let points = 0, tris = 0, cams = 0;
    if (layers.mesh && layers.mesh.on) {
      gl.useProgram(meshProg); gl.uniformMatrix4fv(gl.getUniformLocation(meshProg, "m"), false, mvp);
      gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_2D, layers.mesh.tex);
      gl.uniform1i(gl.getUniformLocation(meshProg, "tex"), 0);
      gl.bindVertexArray(layers.mesh.vao); gl.drawElements(gl.TRIANGLES, layers.mesh.count, gl.UNSIGNED_INT, 0);
      tris = layers.mesh.count / 3;
    }
    gl.useProgram(colourProg); gl.uniformMatrix4fv(gl.getUniformLocation(colourProg, "m"), false, mvp);
    if (layers.points && layers.points.on) {
      gl.uniform1f(gl.getUniformLocation(colourProg, "s"), Math.max(1.0, 2.0 * k));
      points = moving ? Math.ceil(layers.points.count / POINT_STRIDE) : layers.points.count;
      gl.bindVertexArray(layers.points.vao); gl.drawArrays(gl.POINTS, 0, points);
    }
    if (layers.cameras && layers.cameras.on) {
      gl.bindVertexArray(layers.cameras.vao); gl.drawArrays(gl.LINES, 0, layers.cameras.count); cams = S.cameras.length;
    }
    gl.bindVertexArray(null);
    // A draw that failed says so: the GL error after the frame, and a lost context.
    const err = gl.getError();
    if (err !== gl.NO_ERROR && err !== gl.CONTEXT_LOST_WEBGL) stats.errors.push("WebGL error 0x" + err.toString(16) + " in frame " + stats.frames);
    if (gl.isContextLost()) { stats.context_lost = true; points = tris = cams = 0; }
    stats.points = points; stats.triangles = tris; stats.cameras = cams; stats.frames++; stats.through = view.through;
    report();
  }
  // A frame of the moving view, timed to the end of its drawing; the scale follows its cost
  // (the pixels scale as its square), by at most 30 % a frame.
  const pixel = new Uint8Array(4);
  // Waits for the frame's drawing to end (reading one pixel back does).
  function finish() { gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel); }
  function drawMoving() {
    moving = true;
    const t = performance.now();
    draw(); finish();
    const ms = performance.now() - t;
    if (ms > 0) scale = Math.min(1, Math.max(MIN_SCALE, scale * Math.min(1.3, Math.max(0.7, Math.sqrt(FRAME_BUDGET_MS / ms)))));
    stats.scale = scale;
    return ms;
  }
  // The view rests: the still frame at full resolution.
  function rest() { moving = false; draw(); }
  let pending = false;
  function redraw() {
    if (!pending) { pending = true; requestAnimationFrame(() => { pending = false; drawMoving(); }); }
    clearTimeout(restTimer); restTimer = setTimeout(rest, REST_MS);
  }

  // Interaction.
  let drag = null;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("mousedown", (e) => { drag = { x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, pan: e.shiftKey || e.button === 2 }; });
  window.addEventListener("mouseup", (e) => {
    if (drag && Math.hypot(e.clientX - drag.x0, e.clientY - drag.y0) < 3) pick(e);
    drag = null;
  });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y; drag.x = e.clientX; drag.y = e.clientY;
    if (view.through !== null) { view.through = null; }
    if (drag.pan) {
      const f = eyeFrame(), s = view.dist * 0.0015;
      for (let i = 0; i < 3; i++) view.target[i] += (-f.x[i] * dx + f.y[i] * dy) * s;
    } else { view.yaw -= dx * 0.008; view.pitch = Math.max(-1.5, Math.min(1.5, view.pitch + dy * 0.008)); }
    redraw();
  });
  canvas.addEventListener("wheel", (e) => { e.preventDefault(); view.dist *= Math.exp(e.deltaY * 0.001); redraw(); }, { passive: false });
  function pick(e) {
    if (!mvp) return;
    const r = canvas.getBoundingClientRect();
    let best = -1, bd = 14;
    S.cameras.forEach((c, i) => {
      const p = c.c, m = mvp;
      const x = m[0] * p[0] + m[4] * p[1] + m[8] * p[2] + m[12], y = m[1] * p[0] + m[5] * p[1] + m[9] * p[2] + m[13], w = m[3] * p[0] + m[7] * p[1] + m[11] * p[2] + m[15];
      if (w <= 0) return;
      const sx = (x / w * 0.5 + 0.5) * r.width, sy = (0.5 - y / w * 0.5) * r.height;
      const d = Math.hypot(sx - (e.clientX - r.left), sy - (e.clientY - r.top));
      if (d < bd) { bd = d; best = i; }
    });
    if (best >= 0) showCamera(best);
  }
  function showCamera(i) {
    const c = S.cameras[i];
    view.through = i;
    const panel = document.getElementById("hh-photo");
    if (panel) {
      const parts = [];
      if (c.thumb) { const img = document.createElement("img"); img.src = c.thumb; img.alt = ""; parts.push(img); }
      const name = document.createElement("div"); name.className = "hh-name"; name.textContent = c.name; parts.push(name);
      panel.replaceChildren(...parts);
    }
    draw();
  }
  window.handheldShowCamera = showCamera;
  for (const name of ["points", "cameras", "mesh"]) {
    const box = document.getElementById("hh-layer-" + name);
    if (!box) continue;
    if (!layers[name]) { box.disabled = true; box.checked = false; continue; }
    box.addEventListener("change", () => { layers[name].on = box.checked; draw(); });
  }
  // #layers=mesh,points: the layers named on, the others off, through their toggles.
  const shown = /layers=([a-z,]*)/.exec(location.hash);
  if (shown) {
    const names = shown[1].split(",");
    for (const name of ["points", "cameras", "mesh"]) {
      const box = document.getElementById("hh-layer-" + name);
      if (!box || box.disabled) continue;
      box.checked = names.includes(name); box.dispatchEvent(new Event("change"));
    }
  }
  const resetButton = document.getElementById("hh-reset");
  if (resetButton) resetButton.addEventListener("click", reset);
  window.addEventListener("resize", redraw);

  // The cost of a frame of a turning view (drawn synchronously, finished on the GPU): a few
  // frames to settle the scale (and the renderer's first-use costs), then 20 measured; and the
  // still frame at full resolution.
  function measure() {
    const n = 20, settle = 6;
    let total = 0;
    for (let i = 0; i < settle + n; i++) { view.yaw += 0.01; const ms = drawMoving(); if (i >= settle) total += ms; }
    stats.ms_per_frame = total / n;
    moving = false;
    const t0 = performance.now();
    for (let i = 0; i < 5; i++) { view.yaw += 0.01; draw(); finish(); }
    stats.full_ms_per_frame = (performance.now() - t0) / 5;
    view.yaw -= 0.01 * (settle + n + 5);
    draw();
  }
  // First frame; report.html#viewer&camera=N (or #camera=N) opens looking through camera N.
  try {
    draw();
    const m = /camera=(\d+)/.exec(location.hash);
    if (m && S.cameras[+m[1]]) showCamera(+m[1]);
  } catch (err) { stats.errors.push(String(err)); }
  report();
  const through = () => view.through;
  Promise.resolve(atlasLoaded).then(() => {
    try {
      const keep = through();
      measure();
      if (keep !== null) showCamera(keep);
    } catch (err) { stats.errors.push(String(err)); }
    report();
  });
})();
