// polarref 3D view: sparse/dense points and camera frusta, drawn with the canvas 2D API.
// Written for polarref (no library); runs offline from the report file alone.
// Points go into an ImageData buffer with a depth test; frusta are stroked on top.
// Mouse: drag = orbit, shift-drag or right-drag = pan, wheel = zoom, double-click = reset.
(function () {
  "use strict";
  var root = document.getElementById("view3d");
  var canvas = document.getElementById("view3d-canvas");
  var panel = document.getElementById("view3d-controls");
  var data = JSON.parse(document.getElementById("view3d-data").textContent);
  var ctx = canvas.getContext("2d");
  var W = canvas.width, H = canvas.height;

  function bytes(b64) {
    var s = atob(b64), out = new Uint8Array(s.length);
    for (var i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
    return out;
  }
  function hex(h) { return [parseInt(h.substr(1, 2), 16), parseInt(h.substr(3, 2), 16), parseInt(h.substr(5, 2), 16)]; }
  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function add(a, b) { return [a[0] + b[0], a[1] + b[1], a[2] + b[2]]; }
  function mul(a, s) { return [a[0] * s, a[1] * s, a[2] * s]; }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function unit(a) { var n = Math.sqrt(dot(a, a)) || 1; return mul(a, 1 / n); }
  function rot(q) {  // quaternion w x y z -> columns = camera x, y, z axes in the world frame
    var w = q[0], x = q[1], y = q[2], z = q[3];
    return [[1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)],
            [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)],
            [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]];
  }

  var colors = data.colors || {};
  function colorOf(key) {
    if (colors[key]) return colors[key];
    if (key.indexOf("dense:") === 0 && colors[key.substr(6)]) return colors[key.substr(6)];
    return key === "gt-surface" ? "#b0b0b0" : "#000000";
  }
  var clouds = data.clouds.map(function (c) {
    var q = bytes(c.xyz_u16), dv = new DataView(q.buffer), xyz = new Float32Array(c.count * 3);
    for (var i = 0; i < c.count * 3; i++) xyz[i] = c.origin[i % 3] + dv.getUint16(2 * i, true) * c.step[i % 3];
    return { key: c.key, label: c.label, kind: c.kind, n: c.count, xyz: xyz, rgb: bytes(c.rgb_u8), col: hex(colorOf(c.key)) };
  });
  var cams = data.cameras.map(function (c) {
    return { key: c.key, label: c.label, col: colorOf(c.key),
             list: c.poses.map(function (p) { return { c: [p[0], p[1], p[2]], R: rot(p.slice(3)) }; }) };
  });

  // Layers: one toggle per key; a method's key shows its cameras and its sparse points.
  var layers = [], seen = {};
  function addLayer(key, label) { if (!seen[key]) { seen[key] = true; layers.push({ key: key, label: label }); } }
  cams.forEach(function (c) { addLayer(c.key, c.label); });
  clouds.forEach(function (c) { addLayer(c.key, c.label); });
  var visible = {};
  (data.visible || layers.map(function (l) { return l.key; })).forEach(function (k) { visible[k] = true; });
  var byImageColour = false;

  // Scene frame: "up" is the mean of the GT cameras' -y axes (image up), the centre and radius
  // come from the GT cameras and every cloud.
  var gt = cams.length ? cams[0].list : [];
  var up = [0, 0, 1];
  if (gt.length) {
    var u = [0, 0, 0];
    gt.forEach(function (k) { u = add(u, [-k.R[1][0], -k.R[1][1], -k.R[1][2]]); });
    if (dot(u, u) > 1e-12) up = unit(u);
  }
  var e1 = unit(cross(up, Math.abs(up[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0])), e2 = cross(up, e1);
  var lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  function grow(p) { for (var d = 0; d < 3; d++) { lo[d] = Math.min(lo[d], p[d]); hi[d] = Math.max(hi[d], p[d]); } }
  gt.forEach(function (k) { grow(k.c); });
  clouds.forEach(function (c) { for (var i = 0; i < c.n; i += 7) grow([c.xyz[3 * i], c.xyz[3 * i + 1], c.xyz[3 * i + 2]]); });
  if (!isFinite(lo[0])) { lo = [-1, -1, -1]; hi = [1, 1, 1]; }
  var centre0 = mul(add(lo, hi), 0.5), radius = Math.max(1e-9, 0.5 * Math.sqrt(dot(sub(hi, lo), sub(hi, lo))));
  var gaps = [];
  for (var i = 1; i < gt.length; i++) gaps.push(Math.sqrt(dot(sub(gt[i].c, gt[i - 1].c), sub(gt[i].c, gt[i - 1].c))));
  gaps.sort(function (a, b) { return a - b; });
  var frustum = gaps.length ? Math.min(0.8 * gaps[gaps.length >> 1], 0.15 * radius) : 0.08 * radius;
  if (!(frustum > 0)) frustum = 0.08 * radius;
  var tx = data.tan_half_fov[0], ty = data.tan_half_fov[1];

  var view;
  function reset() { view = { yaw: 0.6, pitch: 0.45, dist: 1.8 * radius, target: centre0.slice() }; }
  reset();
  var F = (H / 2) / Math.tan(25 * Math.PI / 180);

  function basis() {
    var cp = Math.cos(view.pitch);
    var dir = add(add(mul(e1, cp * Math.cos(view.yaw)), mul(e2, cp * Math.sin(view.yaw))), mul(up, Math.sin(view.pitch)));
    var eye = add(view.target, mul(dir, view.dist));
    var f = unit(sub(view.target, eye)), r = unit(cross(f, up)), u2 = cross(r, f);
    return { eye: eye, f: f, r: r, u: u2 };
  }
  function project(B, p) {
    var d = sub(p, B.eye), z = dot(d, B.f);
    if (z <= 1e-6 * radius) return null;
    return [W / 2 + F * dot(d, B.r) / z, H / 2 - F * dot(d, B.u) / z, z];
  }

  var img = ctx.createImageData(W, H), pix = new Uint32Array(img.data.buffer), depth = new Float32Array(W * H);
  var BG = 0xfffcfcfc;
  function draw() {
    var B = basis(), drawn = 0;
    pix.fill(BG);
    depth.fill(Infinity);
    var ex = B.eye, f = B.f, r = B.r, u2 = B.u;
    clouds.forEach(function (c) {
      if (!visible[c.key]) return;
      var size = c.kind === "dense" ? 1 : 2, xyz = c.xyz, rgb = c.rgb, col = c.col;
      for (var i = 0; i < c.n; i++) {
        var dx = xyz[3 * i] - ex[0], dy = xyz[3 * i + 1] - ex[1], dz = xyz[3 * i + 2] - ex[2];
        var z = dx * f[0] + dy * f[1] + dz * f[2];
        if (z <= 1e-6 * radius) continue;
        var sx = Math.round(W / 2 + F * (dx * r[0] + dy * r[1] + dz * r[2]) / z);
        var sy = Math.round(H / 2 - F * (dx * u2[0] + dy * u2[1] + dz * u2[2]) / z);
        if (sx < 0 || sy < 0 || sx >= W - size || sy >= H - size) continue;
        var cr = col[0], cg = col[1], cb = col[2];
        if (byImageColour || c.kind === "dense") { cr = rgb[3 * i]; cg = rgb[3 * i + 1]; cb = rgb[3 * i + 2]; }
        var v = (0xff000000 | (cb << 16) | (cg << 8) | cr) >>> 0;
        for (var a = 0; a < size; a++) for (var b = 0; b < size; b++) {
          var k = (sy + a) * W + sx + b;
          if (z < depth[k]) { depth[k] = z; pix[k] = v; }
        }
        drawn++;
      }
    });
    ctx.putImageData(img, 0, 0);
    ctx.lineWidth = 1;
    cams.forEach(function (c) {
      if (!visible[c.key]) return;
      ctx.strokeStyle = c.col;
      ctx.beginPath();
      c.list.forEach(function (k) {
        var X = [k.R[0][0], k.R[0][1], k.R[0][2]], Y = [k.R[1][0], k.R[1][1], k.R[1][2]], Z = [k.R[2][0], k.R[2][1], k.R[2][2]];
        var apex = project(B, k.c), pts = [];
        var corners = [[-1, -1], [1, -1], [1, 1], [-1, 1]];
        for (var j = 0; j < 4; j++) {
          var w = add(k.c, mul(add(add(mul(X, corners[j][0] * tx), mul(Y, corners[j][1] * ty)), Z), frustum));
          pts.push(project(B, w));
        }
        if (!apex || pts.some(function (p) { return !p; })) return;
        for (j = 0; j < 4; j++) {
          ctx.moveTo(apex[0], apex[1]); ctx.lineTo(pts[j][0], pts[j][1]);
          ctx.moveTo(pts[j][0], pts[j][1]); ctx.lineTo(pts[(j + 1) % 4][0], pts[(j + 1) % 4][1]);
        }
        drawn++;
      });
      ctx.stroke();
    });
    canvas.setAttribute("data-drawn", String(drawn));
    canvas.setAttribute("data-frames", String(1 + Number(canvas.getAttribute("data-frames") || 0)));
  }
  var pending = false;
  function redraw() { if (!pending) { pending = true; requestAnimationFrame(function () { pending = false; draw(); }); } }

  // Controls: one checkbox per layer (coloured like its points), colour mode, reset.
  layers.forEach(function (l) {
    var lab = document.createElement("label"), box = document.createElement("input"), sw = document.createElement("span");
    box.type = "checkbox"; box.checked = !!visible[l.key]; box.setAttribute("data-layer", l.key);
    box.addEventListener("change", function () { visible[l.key] = box.checked; redraw(); });
    sw.className = "swatch"; sw.style.background = colorOf(l.key);
    lab.appendChild(box); lab.appendChild(sw); lab.appendChild(document.createTextNode(l.label));
    panel.appendChild(lab);
  });
  var mode = document.createElement("label"), mbox = document.createElement("input");
  mbox.type = "checkbox";
  mbox.addEventListener("change", function () { byImageColour = mbox.checked; redraw(); });
  mode.appendChild(mbox); mode.appendChild(document.createTextNode("image colours"));
  panel.appendChild(mode);
  var btn = document.createElement("button");
  btn.type = "button"; btn.textContent = "reset view";
  btn.addEventListener("click", function () { reset(); redraw(); });
  panel.appendChild(btn);

  var drag = null;
  canvas.addEventListener("contextmenu", function (e) { e.preventDefault(); });
  canvas.addEventListener("mousedown", function (e) {
    drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 };
    e.preventDefault();
  });
  window.addEventListener("mouseup", function () { drag = null; });
  window.addEventListener("mousemove", function (e) {
    if (!drag) return;
    var s = canvas.width / (canvas.clientWidth || canvas.width), dx = (e.clientX - drag.x) * s, dy = (e.clientY - drag.y) * s;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      var B = basis(), k = view.dist / F;
      view.target = add(view.target, add(mul(B.r, -dx * k), mul(B.u, dy * k)));
    } else {
      view.yaw -= dx * 0.008;
      view.pitch = Math.max(-1.55, Math.min(1.55, view.pitch + dy * 0.008));
    }
    redraw();
  });
  canvas.addEventListener("wheel", function (e) {
    e.preventDefault();
    view.dist *= Math.exp(0.0015 * Math.max(-300, Math.min(300, e.deltaY)));
    redraw();
  }, { passive: false });
  canvas.addEventListener("dblclick", function () { reset(); redraw(); });

  draw();
  root.setAttribute("data-ready", "1");
})();
