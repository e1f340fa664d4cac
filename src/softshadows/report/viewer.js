/* softshadows report viewer: flip between methods, the reference, V and the signed error at one zoom/pan.
   Data: <script type="application/json" id="viewer-data"> (see softshadows/report/viewer.py). No network. */
(function () {
  'use strict';
  var root = document.getElementById('viewer');
  var dataEl = document.getElementById('viewer-data');
  if (!root || !dataEl) return;
  var D = JSON.parse(dataEl.textContent);
  var W = D.w, H = D.h, items = D.items, LIMIT = D.limit, QMAX = D.qmax;
  var LAYERS = ['image', 'v', 'error'];
  var canvas = root.querySelector('canvas');
  var g = canvas.getContext('2d');
  var readout = document.getElementById('viewer-readout');
  var S = {cur: items.length > 1 ? 1 : 0, last: items.length > 1 ? 1 : 0, layer: 'image', zoom: 1, tx: 0, ty: 0, fitted: false};
  var cache = {};  // 'i:layer' -> canvas W x H
  var V = [];      // Float32Array per item (NaN = background), null until decoded

  function b64(s) {
    var bin = atob(s), u = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) u[i] = bin.charCodeAt(i);
    return u;
  }
  function decodeV(item) {
    var bytes = b64(item.vq);
    var raw = (typeof DecompressionStream === 'undefined') ? Promise.reject(new Error('no DecompressionStream'))
      : new Response(new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'))).arrayBuffer();
    return raw.then(function (buf) {
      var dv = new DataView(buf), n = W * H, out = new Float32Array(n);
      for (var i = 0; i < n; i++) {
        var q = dv.getUint16(2 * i, true);
        out[i] = q === 65535 ? NaN : q / QMAX;
      }
      return out;
    });
  }
  function lutImage(vals, lut, bg, map) {
    var c = document.createElement('canvas'); c.width = W; c.height = H;
    var cx = c.getContext('2d'), im = cx.createImageData(W, H), d = im.data;
    for (var i = 0; i < W * H; i++) {
      var x = vals(i), r, gg, b;
      if (x !== x) { r = bg[0]; gg = bg[1]; b = bg[2]; }
      else { var k = map(x) * 3; r = lut[k]; gg = lut[k + 1]; b = lut[k + 2]; }
      d[4 * i] = r; d[4 * i + 1] = gg; d[4 * i + 2] = b; d[4 * i + 3] = 255;
    }
    cx.putImageData(im, 0, 0);
    return c;
  }
  function clampIdx(t) { return Math.max(0, Math.min(255, Math.round(t * 255))); }
  function layerCanvas(i, layer) {
    var key = i + ':' + layer;
    if (cache[key]) return cache[key];
    if (layer === 'image') return items[i].img && items[i].img.complete ? (cache[key] = items[i].img) : null;
    var v = V[i], ref = V[0];
    if (!v || !ref) return null;
    if (layer === 'v') {
      cache[key] = lutImage(function (k) { return v[k]; }, D.lut_v, D.bg_v, clampIdx);
    } else {
      cache[key] = lutImage(function (k) { return v[k] - ref[k]; }, D.lut_err, D.bg_err,
        function (e) { return clampIdx(e / (2 * LIMIT) + 0.5); });
    }
    return cache[key];
  }

  function resize() {
    var dpr = window.devicePixelRatio || 1, r = canvas.getBoundingClientRect();
    canvas.width = Math.max(1, Math.round(r.width * dpr));
    canvas.height = Math.max(1, Math.round(r.height * dpr));
    if (!S.fitted) fit();
    draw();
  }
  function fit() {
    var r = canvas.getBoundingClientRect();
    var z = Math.min(r.width / W, r.height / H);
    S.zoom = z >= 1 ? Math.floor(z) : z;  // whole texels per pixel when it fits: every pixel the same size
    S.tx = (r.width - W * S.zoom) / 2; S.ty = (r.height - H * S.zoom) / 2; S.fitted = true;
  }
  function draw() {
    var dpr = window.devicePixelRatio || 1;
    g.setTransform(1, 0, 0, 1, 0, 0);
    g.fillStyle = '#202024'; g.fillRect(0, 0, canvas.width, canvas.height);
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.imageSmoothingEnabled = false;  // crisp texels when zoomed
    var src = layerCanvas(S.cur, S.layer);
    if (src) g.drawImage(src, S.tx, S.ty, W * S.zoom, H * S.zoom);
    var it = items[S.cur];
    root.dataset.method = it.name; root.dataset.layer = S.layer;
    root.dataset.zoom = S.zoom.toFixed(4); root.dataset.tx = S.tx.toFixed(2); root.dataset.ty = S.ty.toFixed(2);
    var bs = root.querySelectorAll('button[data-item]');
    for (var k = 0; k < bs.length; k++) bs[k].classList.toggle('on', +bs[k].dataset.item === S.cur);
    bs = root.querySelectorAll('button[data-layer]');
    for (k = 0; k < bs.length; k++) bs[k].classList.toggle('on', bs[k].dataset.layer === S.layer);
    var cap = document.getElementById('viewer-caption');
    if (cap) cap.textContent = it.name + ' \u00b7 ' + {image: 'shaded', v: 'V', error: 'signed error V \u2212 V_ref (\u00b1' + LIMIT + ')'}[S.layer]
      + (it.caption ? ' \u00b7 ' + it.caption : '') + ' \u00b7 zoom ' + S.zoom.toFixed(2) + 'x';
    if (S.mx !== undefined) hover(S.mx, S.my);
  }
  function select(i) {
    if (typeof i === 'string') { for (var k = 0; k < items.length; k++) if (items[k].name === i) { i = k; break; } }
    if (typeof i !== 'number' || i < 0 || i >= items.length) return;
    if (i !== 0) S.last = i;
    S.cur = i; draw();
  }
  function setLayer(l) { if (LAYERS.indexOf(l) >= 0) { S.layer = l; draw(); } }
  function zoomAt(f, mx, my) {
    var z = Math.max(0.1, Math.min(128, S.zoom * f)); f = z / S.zoom;
    S.tx = mx - (mx - S.tx) * f; S.ty = my - (my - S.ty) * f; S.zoom = z; draw();
  }
  function fmt(x) { return x !== x ? 'background' : x.toFixed(4); }
  function hover(mx, my) {
    S.mx = mx; S.my = my;
    var x = Math.floor((mx - S.tx) / S.zoom), y = Math.floor((my - S.ty) / S.zoom);
    if (x < 0 || y < 0 || x >= W || y >= H) { readout.textContent = 'outside the image'; readout.dataset.x = ''; return; }
    var k = y * W + x, it = items[S.cur];
    if (!V[S.cur] || !V[0]) { readout.textContent = '(' + x + ', ' + y + ') V values unavailable in this browser'; return; }
    var v = V[S.cur][k], r = V[0][k], e = v - r;
    readout.dataset.x = x; readout.dataset.y = y;
    readout.textContent = '(' + x + ', ' + y + ')  ' + it.name + ' V = ' + fmt(v) + '   ' + items[0].name + ' V = ' + fmt(r)
      + '   error = ' + (e !== e ? 'background' : (e >= 0 ? '+' : '') + e.toFixed(4));
  }

  // events: wheel zoom about the cursor, drag pan, hover readout, keys, buttons, #viewer?m=NAME links
  canvas.addEventListener('wheel', function (ev) {
    ev.preventDefault();
    var r = canvas.getBoundingClientRect();
    zoomAt(Math.exp(-ev.deltaY * 0.002), ev.clientX - r.left, ev.clientY - r.top);
  }, {passive: false});
  var drag = null;
  canvas.addEventListener('pointerdown', function (ev) {
    drag = {x: ev.clientX, y: ev.clientY, tx: S.tx, ty: S.ty}; canvas.setPointerCapture(ev.pointerId);
  });
  canvas.addEventListener('pointermove', function (ev) {
    var r = canvas.getBoundingClientRect();
    if (drag) { S.tx = drag.tx + ev.clientX - drag.x; S.ty = drag.ty + ev.clientY - drag.y; draw(); }
    hover(ev.clientX - r.left, ev.clientY - r.top);
  });
  canvas.addEventListener('pointerup', function () { drag = null; });
  canvas.addEventListener('pointerleave', function () { S.mx = undefined; });
  document.addEventListener('keydown', function (ev) {
    if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
    var t = ev.target && ev.target.tagName;
    if (t === 'INPUT' || t === 'TEXTAREA' || t === 'SELECT') return;
    var k = ev.key, r = canvas.getBoundingClientRect();
    if (k >= '1' && k <= '9') select(+k - 1);
    else if (k === 'ArrowRight' || k === ']') select((S.cur + 1) % items.length);
    else if (k === 'ArrowLeft' || k === '[') select((S.cur + items.length - 1) % items.length);
    else if (k === 'r') select(S.cur === 0 ? S.last : 0);
    else if (k === 's') setLayer('image');
    else if (k === 'v') setLayer('v');
    else if (k === 'e') setLayer('error');
    else if (k === '0' || k === 'f') { fit(); draw(); }
    else if (k === '+' || k === '=') zoomAt(1.25, r.width / 2, r.height / 2);
    else if (k === '-') zoomAt(0.8, r.width / 2, r.height / 2);
    else return;
    ev.preventDefault();
  });
  root.addEventListener('click', function (ev) {
    var b = ev.target.closest('button');
    if (!b) return;
    if (b.dataset.item !== undefined) select(+b.dataset.item);
    else if (b.dataset.layer) setLayer(b.dataset.layer);
    else if (b.dataset.act === 'fit') { fit(); draw(); }
  });
  function fromHash() {
    var m = /^#viewer\?(.*)$/.exec(location.hash);
    if (!m) return;
    m[1].split('&').forEach(function (kv) {
      var p = kv.split('='), v = decodeURIComponent(p[1] || '');
      if (p[0] === 'm') select(v); else if (p[0] === 'l') setLayer(v);
    });
    root.scrollIntoView();
  }
  window.addEventListener('hashchange', fromHash);
  window.addEventListener('resize', resize);
  window.ssViewer = {select: select, layer: setLayer, fit: function () { fit(); draw(); }, state: function () { return S; }};

  var pending = [];
  items.forEach(function (it, i) {
    it.img = new Image();
    pending.push(new Promise(function (ok) { it.img.onload = ok; it.img.onerror = ok; }));
    it.img.src = it.image;
    pending.push(decodeV(it).then(function (a) { V[i] = a; }, function (err) { root.dataset.error = String(err); }));
  });
  resize();
  fromHash();
  Promise.all(pending).then(function () { cache = {}; draw(); root.dataset.ready = '1'; });
})();
