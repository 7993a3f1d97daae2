/* gibench comparison viewer: linear float images tone-mapped in a <canvas>.
 *
 * Data comes from <script src="data/*.js"> files (file:// pages cannot fetch()): each registers
 * GIBENCH.views["scene/view"] = {width, height, auto_ev, components: {name: {sources: [{id, label,
 * kind, blob}], reference, eps, scale: {abs, rel}}}, blobs: {blob: base64 float16 RGB, row 0 at the top}}.
 * A wipe slider splits the canvas between images A (left) and B (right); wheel zooms about the
 * cursor, drag pans, double-click resets. Exposure is in stops; display is sRGB. Error maps are
 * |L_A - L_ref| (or relative to L_ref + eps) in false colour on one scale per scene and component.
 */
(function () {
  "use strict";
  var G = window.GIBENCH = window.GIBENCH || {};
  G.views = G.views || {};

  var HALF = (function () {
    var t = new Float32Array(65536);
    for (var h = 0; h < 65536; h++) {
      var s = (h & 0x8000) ? -1 : 1, e = (h >> 10) & 0x1f, m = h & 0x3ff;
      if (e === 0) t[h] = s * m * Math.pow(2, -24);
      else if (e === 31) t[h] = m ? NaN : s * Infinity;
      else t[h] = s * (1 + m / 1024) * Math.pow(2, e - 15);
    }
    return t;
  })();

  function decode(b64) {
    var bin = atob(b64), n = bin.length >> 1, out = new Float32Array(n);
    for (var i = 0; i < n; i++) out[i] = HALF[bin.charCodeAt(2 * i) | (bin.charCodeAt(2 * i + 1) << 8)];
    return out;
  }

  function srgb8(v) {
    if (!(v > 0)) return 0;
    if (v >= 1) return 255;
    var c = v <= 0.0031308 ? 12.92 * v : 1.055 * Math.pow(v, 1 / 2.4) - 0.055;
    return Math.round(c * 255);
  }

  function lum(d, i) { return 0.2126 * d[i] + 0.7152 * d[i + 1] + 0.0722 * d[i + 2]; }

  function colormapRgb(t) {
    var lut = G.colormap, k = Math.max(0, Math.min(255, Math.floor(t * 255.999)));
    return [lut[3 * k], lut[3 * k + 1], lut[3 * k + 2]];
  }

  /* RGBA bytes of one source: tone-mapped image, or its error map against the reference. */
  function rasterize(pixels, ref, mode, ev, comp, n) {
    var out = new Uint8ClampedArray(n * 4), gain = Math.pow(2, ev);
    for (var p = 0, i = 0; p < n; p++, i += 3) {
      var o = 4 * p;
      if (mode === "image" || !ref) {
        out[o] = srgb8(pixels[i] * gain); out[o + 1] = srgb8(pixels[i + 1] * gain); out[o + 2] = srgb8(pixels[i + 2] * gain);
      } else {
        var lr = lum(ref, i), err = Math.abs(lum(pixels, i) - lr);
        var scale = comp.scale[mode];
        if (mode === "rel") err = err / (Math.abs(lr) + comp.eps);
        var c = colormapRgb(scale > 0 ? err / scale : 0);
        out[o] = c[0]; out[o + 1] = c[1]; out[o + 2] = c[2];
      }
      out[o + 3] = 255;
    }
    return out;
  }

  function el(tag, attrs, text) {
    var e = document.createElement(tag);
    for (var k in attrs || {}) e.setAttribute(k, attrs[k]);
    if (text !== undefined) e.textContent = text;
    return e;
  }

  function Viewer(root, view) {
    this.root = root; this.view = view;
    this.w = view.width; this.h = view.height; this.n = view.width * view.height;
    this.decoded = {};
    this.comp = view.default_component in view.components ? view.default_component : Object.keys(view.components)[0];
    this.mode = "image"; this.ev = view.auto_ev; this.split = 0.5;
    this.zoom = 1; this.panX = 0; this.panY = 0;
    this.build();
    this.setComponent(this.comp);
  }

  Viewer.prototype.pixels = function (comp, id) {
    var key = comp + "/" + id;
    if (!this.decoded[key]) {
      var src = this.view.components[comp].sources.filter(function (s) { return s.id === id; })[0];
      this.decoded[key] = this.decoded["blob/" + src.blob] || decode(this.view.blobs[src.blob]);
      this.decoded["blob/" + src.blob] = this.decoded[key];
    }
    return this.decoded[key];
  };

  Viewer.prototype.build = function () {
    var self = this, root = this.root;
    var bar = el("div", {"class": "controls"});
    this.compButtons = {};
    var compGroup = el("div", {"class": "btn-group", role: "group"});
    Object.keys(this.view.components).forEach(function (c) {
      var b = el("button", {type: "button", "data-component": c}, self.view.components[c].label);
      b.addEventListener("click", function () { self.setComponent(c); });
      compGroup.appendChild(b); self.compButtons[c] = b;
    });
    bar.appendChild(compGroup);
    this.selA = el("select", {"class": "sel-a", "aria-label": "left image"});
    this.selB = el("select", {"class": "sel-b", "aria-label": "right image"});
    [this.selA, this.selB].forEach(function (s) { s.addEventListener("change", function () { self.refresh(); }); });
    var lab = el("label", {}, "A "); lab.appendChild(this.selA); bar.appendChild(lab);
    var swap = el("button", {type: "button", "class": "swap", title: "swap A and B"}, "\u21c4");
    swap.addEventListener("click", function () {
      var a = self.selA.value; self.selA.value = self.selB.value; self.selB.value = a; self.refresh();
    });
    bar.appendChild(swap);
    lab = el("label", {}, "B "); lab.appendChild(this.selB); bar.appendChild(lab);
    this.selMode = el("select", {"class": "sel-mode", "aria-label": "display"});
    [["image", "image"], ["abs", "error |\u0394L|"], ["rel", "relative error"]].forEach(function (m) {
      self.selMode.appendChild(el("option", {value: m[0]}, m[1]));
    });
    this.selMode.addEventListener("change", function () { self.mode = self.selMode.value; self.refresh(); });
    lab = el("label", {}, "show "); lab.appendChild(this.selMode); bar.appendChild(lab);
    root.appendChild(bar);

    var bar2 = el("div", {"class": "controls"});
    this.exposure = el("input", {type: "range", "class": "exposure", min: "-10", max: "10", step: "0.1", value: String(this.ev)});
    this.evText = el("span", {"class": "ev"});
    this.exposure.addEventListener("input", function () { self.ev = parseFloat(self.exposure.value); self.refresh(); });
    lab = el("label", {}, "exposure "); lab.appendChild(this.exposure); lab.appendChild(this.evText); bar2.appendChild(lab);
    this.wipe = el("input", {type: "range", "class": "wipe", min: "0", max: "1000", step: "1", value: "500"});
    this.wipe.addEventListener("input", function () { self.split = parseInt(self.wipe.value, 10) / 1000; self.draw(); });
    lab = el("label", {}, "wipe A | B "); lab.appendChild(this.wipe); bar2.appendChild(lab);
    var reset = el("button", {type: "button", "class": "reset"}, "reset view");
    reset.addEventListener("click", function () { self.zoom = 1; self.panX = 0; self.panY = 0; self.draw(); });
    bar2.appendChild(reset);
    root.appendChild(bar2);

    var stage = el("div", {"class": "stage"});
    this.canvas = el("canvas", {"class": "view-canvas"});
    stage.appendChild(this.canvas);
    this.labelA = el("span", {"class": "tag tag-a"}); this.labelB = el("span", {"class": "tag tag-b"});
    stage.appendChild(this.labelA); stage.appendChild(this.labelB);
    root.appendChild(stage);
    var cw = Math.min(640, Math.max(320, root.clientWidth || 640));
    var s = Math.max(1, Math.floor(cw / this.w));
    this.canvas.width = this.w * s; this.canvas.height = this.h * s;
    this.offA = el("canvas"); this.offB = el("canvas");
    [this.offA, this.offB].forEach(function (c) { c.width = self.w; c.height = self.h; });

    this.legend = el("div", {"class": "legend"});
    this.bar = el("canvas", {"class": "colorbar", width: "256", height: "12"});
    this.legendLo = el("span", {}, "0"); this.legendHi = el("span", {});
    this.legend.appendChild(el("span", {"class": "legend-title"}, "error scale "));
    this.legend.appendChild(this.legendLo); this.legend.appendChild(this.bar); this.legend.appendChild(this.legendHi);
    root.appendChild(this.legend);
    var bctx = this.bar.getContext("2d"), img = bctx.createImageData(256, 12);
    for (var x = 0; x < 256; x++) {
      var c = colormapRgb(x / 255);
      for (var y = 0; y < 12; y++) { var o = 4 * (y * 256 + x); img.data[o] = c[0]; img.data[o + 1] = c[1]; img.data[o + 2] = c[2]; img.data[o + 3] = 255; }
    }
    bctx.putImageData(img, 0, 0);
    this.thumbs = el("div", {"class": "thumbs"});
    root.appendChild(this.thumbs);

    var drag = null;
    this.canvas.addEventListener("wheel", function (ev) {
      ev.preventDefault();
      var r = self.canvas.getBoundingClientRect();
      var mx = (ev.clientX - r.left) * self.canvas.width / r.width, my = (ev.clientY - r.top) * self.canvas.height / r.height;
      var f = ev.deltaY < 0 ? 1.25 : 0.8, z = Math.max(1, Math.min(64, self.zoom * f));
      f = z / self.zoom;
      self.panX = mx - (mx - self.panX) * f; self.panY = my - (my - self.panY) * f; self.zoom = z;
      self.clampPan(); self.draw();
    }, {passive: false});
    this.canvas.addEventListener("mousedown", function (ev) { drag = {x: ev.clientX, y: ev.clientY, px: self.panX, py: self.panY}; });
    window.addEventListener("mouseup", function () { drag = null; });
    window.addEventListener("mousemove", function (ev) {
      if (!drag) return;
      var r = self.canvas.getBoundingClientRect(), k = self.canvas.width / r.width;
      self.panX = drag.px + (ev.clientX - drag.x) * k; self.panY = drag.py + (ev.clientY - drag.y) * k;
      self.clampPan(); self.draw();
    });
    this.canvas.addEventListener("dblclick", function () { self.zoom = 1; self.panX = 0; self.panY = 0; self.draw(); });
  };

  Viewer.prototype.clampPan = function () {
    var W = this.canvas.width, H = this.canvas.height;
    this.panX = Math.min(0, Math.max(W - W * this.zoom, this.panX));
    this.panY = Math.min(0, Math.max(H - H * this.zoom, this.panY));
  };

  Viewer.prototype.setComponent = function (c) {
    var self = this, comp = this.view.components[c], prevA = this.selA.value, prevB = this.selB.value;
    this.comp = c;
    Object.keys(this.compButtons).forEach(function (k) { self.compButtons[k].classList.toggle("active", k === c); });
    [this.selA, this.selB].forEach(function (s) {
      s.innerHTML = "";
      comp.sources.forEach(function (src) { s.appendChild(el("option", {value: src.id}, src.label)); });
    });
    var ids = comp.sources.map(function (s) { return s.id; });
    var methods = comp.sources.filter(function (s) { return s.kind === "method"; }).map(function (s) { return s.id; });
    this.selA.value = ids.indexOf(prevA) >= 0 ? prevA : (comp.reference || ids[0]);
    this.selB.value = ids.indexOf(prevB) >= 0 ? prevB : (methods[methods.length - 1] || ids[ids.length - 1]);
    var hasRef = !!comp.reference;
    Array.prototype.forEach.call(this.selMode.options, function (o) { o.disabled = o.value !== "image" && !hasRef; });
    if (!hasRef) { this.mode = "image"; this.selMode.value = "image"; }
    this.buildThumbs();
    this.refresh();
  };

  Viewer.prototype.buildThumbs = function () {
    var self = this, comp = this.view.components[this.comp];
    this.thumbs.innerHTML = "";
    if (!comp.reference) {
      this.thumbs.appendChild(el("p", {"class": "note"}, "No reference for this component: error maps unavailable."));
      return;
    }
    var ref = this.pixels(this.comp, comp.reference);
    comp.sources.forEach(function (src) {
      if (src.kind !== "method") return;
      var fig = el("figure", {"class": "thumb"}), c = el("canvas", {width: String(self.w), height: String(self.h)});
      var data = rasterize(self.pixels(self.comp, src.id), ref, "abs", 0, comp, self.n);
      c.getContext("2d").putImageData(new ImageData(data, self.w, self.h), 0, 0);
      c.title = "show " + src.label + " in B";
      c.addEventListener("click", function () { self.selB.value = src.id; self.refresh(); });
      fig.appendChild(c); fig.appendChild(el("figcaption", {}, src.label));
      self.thumbs.appendChild(fig);
    });
  };

  Viewer.prototype.refresh = function () {
    var comp = this.view.components[this.comp];
    var ref = comp.reference ? this.pixels(this.comp, comp.reference) : null;
    var a = this.selA.value, b = this.selB.value;
    this.offA.getContext("2d").putImageData(new ImageData(rasterize(this.pixels(this.comp, a), ref, this.mode, this.ev, comp, this.n), this.w, this.h), 0, 0);
    this.offB.getContext("2d").putImageData(new ImageData(rasterize(this.pixels(this.comp, b), ref, this.mode, this.ev, comp, this.n), this.w, this.h), 0, 0);
    this.labelA.textContent = "A: " + this.selA.options[this.selA.selectedIndex].text;
    this.labelB.textContent = "B: " + this.selB.options[this.selB.selectedIndex].text;
    this.evText.textContent = (this.ev >= 0 ? "+" : "") + this.ev.toFixed(1) + " EV";
    var showLegend = this.mode !== "image";
    this.legend.style.visibility = comp.reference ? "visible" : "hidden";
    var scale = comp.scale ? comp.scale[showLegend ? this.mode : "abs"] : 0;
    this.legendHi.textContent = (scale || 0).toPrecision(3) + (this.mode === "rel" ? " (relative)" : "");
    this.draw();
  };

  Viewer.prototype.draw = function () {
    var ctx = this.canvas.getContext("2d"), W = this.canvas.width, H = this.canvas.height;
    ctx.imageSmoothingEnabled = false;
    ctx.fillStyle = "#111"; ctx.fillRect(0, 0, W, H);
    var sx = W * this.zoom / this.w, sy = H * this.zoom / this.h;
    var splitX = Math.round(this.split * W);
    ctx.save(); ctx.beginPath(); ctx.rect(0, 0, splitX, H); ctx.clip();
    ctx.setTransform(sx, 0, 0, sy, this.panX, this.panY); ctx.drawImage(this.offA, 0, 0);
    ctx.restore();
    ctx.save(); ctx.beginPath(); ctx.rect(splitX, 0, W - splitX, H); ctx.clip();
    ctx.setTransform(sx, 0, 0, sy, this.panX, this.panY); ctx.drawImage(this.offB, 0, 0);
    ctx.restore();
    ctx.fillStyle = "rgba(255,255,255,0.85)"; ctx.fillRect(splitX - 1, 0, 2, H);
  };

  G.start = function () {
    G.viewers = [];
    Array.prototype.forEach.call(document.querySelectorAll(".viewer[data-view]"), function (root) {
      var view = G.views[root.getAttribute("data-view")];
      if (!view) { root.appendChild(el("p", {"class": "note"}, "image data missing")); return; }
      G.viewers.push(new Viewer(root, view));
    });
    Array.prototype.forEach.call(document.querySelectorAll("select.metric-select"), function (sel) {
      var target = document.getElementById(sel.getAttribute("data-target"));
      function show() {
        Array.prototype.forEach.call(target.querySelectorAll("[data-metric]"), function (t) {
          t.hidden = t.getAttribute("data-metric") !== sel.value;
        });
      }
      sel.addEventListener("change", show); show();
    });
    G.ready = true;
  };
  document.addEventListener("DOMContentLoaded", G.start);
})();
