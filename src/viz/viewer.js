// depthcal report viewer: an orthographic point splatter on a 2-D canvas with a depth buffer, the same
// projection, shading and colours as the PNG snapshots (src/viz/render.rs). No network, no libraries.
(function () {
  'use strict';
  var status = document.getElementById('viewer-status');
  try {
    var data = JSON.parse(document.getElementById('report-data').textContent);
    var sc = data.scene;
    var canvas = document.getElementById('viewer');
    if (!sc || !canvas) { return; }
    var ctx = canvas.getContext('2d');
    var W = canvas.width, H = canvas.height;

    function bytes(b64) {
      var s = atob(b64), u = new Uint8Array(s.length);
      for (var i = 0; i < s.length; i++) { u[i] = s.charCodeAt(i); }
      return new DataView(u.buffer);
    }
    // Point sets: 16 bits per coordinate over each set's bounding box, little-endian.
    var sets = sc.sets.map(function (s) {
      var dv = bytes(s.data), p = new Float32Array(3 * s.count);
      for (var i = 0; i < 3 * s.count; i++) {
        var k = i % 3;
        p[i] = s.origin[k] + dv.getUint16(2 * i, true) * s.scale[k];
      }
      return p;
    });
    // Residuals: 16 bits in units of `quantum`; 65535 = no counterpart (NaN).
    var residuals = sc.residuals.map(function (r) {
      var dv = bytes(r.data), n = dv.byteLength / 2, v = new Float32Array(n);
      for (var i = 0; i < n; i++) {
        var q = dv.getUint16(2 * i, true);
        v[i] = q === 65535 ? NaN : q * r.quantum;
      }
      return v;
    });
    var items = sc.items.map(function (it) { return Object.assign({ on: it.visible }, it); });
    var cam0 = sc.camera;
    var view = {};
    var mode = 'item';
    var psize = sc.point_size;

    function reset() {
      view = { az: cam0.azimuth_deg, el: cam0.elevation_deg, zoom: 1, px: 0, py: 0 };
    }
    reset();

    function colormap(t) {
      var m = sc.colormap, n = m.length - 1;
      if (!(t > 0)) { t = 0; }
      if (t > 1) { t = 1; }
      var x = t * n, k = Math.min(Math.floor(x), n - 1), f = x - k, a = m[k], b = m[k + 1];
      return [Math.round(a[0] + (b[0] - a[0]) * f), Math.round(a[1] + (b[1] - a[1]) * f),
        Math.round(a[2] + (b[2] - a[2]) * f)];
    }

    // View basis rows (right, up, toward the viewer) and the item's transform composed with it.
    function basis() {
      var az = view.az * Math.PI / 180, el = view.el * Math.PI / 180;
      var e = [Math.cos(el) * Math.cos(az), Math.cos(el) * Math.sin(az), Math.sin(el)];
      var r = [-Math.sin(az), Math.cos(az), 0];
      var u = [e[1] * r[2] - e[2] * r[1], e[2] * r[0] - e[0] * r[2], e[0] * r[1] - e[1] * r[0]];
      return [r, u, e];
    }
    function compose(B, T) {
      // v = B (R p + t - c): A = B R, b = B (t - c).
      var A = [], b = [], c = cam0.center;
      for (var i = 0; i < 3; i++) {
        A.push([0, 1, 2].map(function (j) {
          return B[i][0] * T[j] + B[i][1] * T[4 + j] + B[i][2] * T[8 + j];
        }));
        b.push(B[i][0] * (T[3] - c[0]) + B[i][1] * (T[7] - c[1]) + B[i][2] * (T[11] - c[2]));
      }
      return { A: A, b: b };
    }

    function draw() {
      var img = ctx.createImageData(W, H), px = img.data, zb = new Float32Array(W * H);
      var bg = sc.background, i, k;
      zb.fill(-Infinity);
      for (i = 0; i < W * H; i++) { px[4 * i] = bg[0]; px[4 * i + 1] = bg[1]; px[4 * i + 2] = bg[2]; px[4 * i + 3] = 255; }
      var B = basis(), s = view.zoom * sc.fill * Math.min(W, H) / (2 * cam0.radius);
      var cx = W / 2 + view.px, cy = H / 2 + view.py, rad = cam0.depth_radius, size = psize, half = size / 2;
      var drawn = 0;
      items.forEach(function (it) {
        if (!it.on || it.kind !== 'points') { return; }
        var p = sets[it.set], n = p.length / 3, M = compose(B, it.transform), A = M.A, b = M.b;
        var res = it.residual === null ? null : residuals[it.residual];
        var base = mode === 'residual' ? (res ? null : sc.reference_grey) : it.rgb;
        var bias = mode === 'residual' && !res ? sc.depth_bias * rad : 0;
        for (k = 0; k < n; k++) {
          var x = p[3 * k], y = p[3 * k + 1], z = p[3 * k + 2];
          var vx = A[0][0] * x + A[0][1] * y + A[0][2] * z + b[0];
          var vy = A[1][0] * x + A[1][1] * y + A[1][2] * z + b[1];
          var d = A[2][0] * x + A[2][1] * y + A[2][2] * z + b[2];
          var X = cx + s * vx, Y = cy - s * vy;
          if (!(X >= 0 && Y >= 0 && X < W && Y < H)) { continue; }
          drawn++;
          var c = base;
          if (!c) {
            var r = res[k];
            c = r !== r ? sc.unmatched : colormap(r / sc.residual_max);
          }
          var f = Math.min(1, Math.max(0.3, 0.45 + 0.55 * (d / rad + 1) / 2));
          var x0 = Math.round(X - half), y0 = Math.round(Y - half);
          for (var yy = Math.max(0, y0); yy < Math.min(H, y0 + size); yy++) {
            for (var xx = Math.max(0, x0); xx < Math.min(W, x0 + size); xx++) {
              var q = yy * W + xx;
              if (d - bias > zb[q]) {
                zb[q] = d - bias;
                px[4 * q] = Math.round(c[0] * f); px[4 * q + 1] = Math.round(c[1] * f); px[4 * q + 2] = Math.round(c[2] * f);
              }
            }
          }
        }
      });
      ctx.putImageData(img, 0, 0);
      ctx.lineWidth = 2;
      items.forEach(function (it) {
        if (!it.on || it.kind !== 'lines') { return; }
        var M = compose(B, it.transform), A = M.A, b = M.b;
        function pr(x, y, z) {
          return [cx + s * (A[0][0] * x + A[0][1] * y + A[0][2] * z + b[0]),
            cy - s * (A[1][0] * x + A[1][1] * y + A[1][2] * z + b[1])];
        }
        it.segments.forEach(function (g) {
          var a = pr(g[0], g[1], g[2]), e = pr(g[3], g[4], g[5]);
          ctx.strokeStyle = 'rgb(' + g[6] + ',' + g[7] + ',' + g[8] + ')';
          ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(e[0], e[1]); ctx.stroke();
        });
      });
      document.getElementById('points-drawn').textContent = String(drawn);
      var shown = items.reduce(function (a, it) {
        return a + (it.on && it.kind === 'points' ? sets[it.set].length / 3 : 0);
      }, 0);
      document.getElementById('points-embedded').textContent = String(shown);
      status.textContent = 'drawn (' + (mode === 'residual' ? 'residual colours' : 'colours by cloud') + ')';
      document.body.setAttribute('data-viewer', 'drawn');
    }

    var pending = false;
    function redraw() {
      if (pending) { return; }
      pending = true;
      window.requestAnimationFrame(function () { pending = false; draw(); });
    }

    // Toggles, colouring, point size.
    var box = document.getElementById('viewer-items');
    items.forEach(function (it, i) {
      var l = document.createElement('label'), cb = document.createElement('input'), chip = document.createElement('span');
      cb.type = 'checkbox'; cb.checked = it.on; cb.id = 'item-' + i;
      cb.addEventListener('change', function () { it.on = cb.checked; redraw(); });
      chip.className = 'chip';
      if (it.kind === 'points') {
        chip.style.background = 'rgb(' + it.rgb.join(',') + ')';
      } else {
        chip.style.border = '2px solid #999';
        chip.style.width = '8px'; chip.style.height = '8px';
      }
      l.appendChild(cb); l.appendChild(chip); l.appendChild(document.createTextNode(it.name));
      box.appendChild(l);
    });
    var sel = document.getElementById('colouring');
    sel.addEventListener('change', function () { mode = sel.value; redraw(); });
    var ps = document.getElementById('point-size');
    ps.value = String(psize);
    ps.addEventListener('input', function () { psize = parseInt(ps.value, 10) || 1; redraw(); });
    document.getElementById('reset').addEventListener('click', function () { reset(); redraw(); });

    // Orbit (drag), pan (shift-drag or right-drag), zoom (wheel), reset (double-click).
    var drag = null;
    canvas.addEventListener('contextmenu', function (e) { e.preventDefault(); });
    canvas.addEventListener('pointerdown', function (e) {
      drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 };
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener('pointermove', function (e) {
      if (!drag) { return; }
      var dx = e.clientX - drag.x, dy = e.clientY - drag.y, sx = W / canvas.clientWidth;
      drag.x = e.clientX; drag.y = e.clientY;
      if (drag.pan) {
        view.px += dx * sx; view.py += dy * sx;
      } else {
        view.az -= dx * 0.4;
        view.el = Math.max(-89, Math.min(89, view.el + dy * 0.4));
      }
      redraw();
    });
    canvas.addEventListener('pointerup', function () { drag = null; });
    canvas.addEventListener('wheel', function (e) {
      e.preventDefault();
      view.zoom = Math.max(0.05, Math.min(200, view.zoom * Math.exp(-e.deltaY * 0.0015)));
      redraw();
    }, { passive: false });
    canvas.addEventListener('dblclick', function () { reset(); redraw(); });
    draw();
  } catch (err) {
    if (status) { status.textContent = 'not drawn: ' + err; }
    document.body.setAttribute('data-viewer', 'failed');
  }
})();
