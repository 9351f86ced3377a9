// bondc report: zoom and pan the time axis of the plots, offline. Drag across a plot to zoom into
// that span, Shift+drag to pan, double-click to see the whole run again. Each zoomable plot's
// data-zoom holds numbers only (written by bondc's render.zoom_data): the data area, the x range
// and every line's samples; the zoomed view is drawn from them, new x ticks included.
(function () {
  "use strict";
  var NS = "http://www.w3.org/2000/svg", XMAX = 4294967295, YMAX = 65534, GAP = 65535;

  function inflate(text) {                      // base64 of zlib data -> a promise of its bytes
    var bytes = Uint8Array.from(atob(text), function (c) { return c.charCodeAt(0); });
    return new Response(new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"))).arrayBuffer();
  }

  function samples(line, buffer) {              // differences of uint32 x, then of uint16 y -> the values
    var n = buffer.byteLength / 6, t = new Uint32Array(buffer, 0, n), y = new Uint16Array(buffer, 4 * n, n);
    for (var i = 1; i < n; i++) { t[i] += t[i - 1]; y[i] += y[i - 1]; }
    line.t = t;
    line.y = y;
  }

  function first(t, f) {                        // the first index with t[i] >= f (binary search)
    var lo = 0, hi = t.length;
    while (lo < hi) { var mid = (lo + hi) >> 1; if (t[mid] < f) lo = mid + 1; else hi = mid; }
    return lo;
  }

  function ticks(a, b) {                        // about six round values in [a, b]
    var span = (b - a) / 6, step = Math.pow(10, Math.floor(Math.log10(span)));
    step *= span > 5 * step ? 10 : span > 2 * step ? 5 : span > step ? 2 : 1;
    var values = [];
    for (var k = Math.ceil(a / step); k * step <= b + step * 1e-9; k++) values.push(k * step);
    var decimals = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
    return values.map(function (v) { return [v, (Math.abs(v) < step / 2 ? 0 : v).toFixed(decimals).replace("-", "\u2212")]; });
  }

  function element(name, attributes) {
    var node = document.createElementNS(NS, name);
    for (var key in attributes) node.setAttribute(key, attributes[key]);
    return node;
  }

  function setup(svg) {
    var zoom = JSON.parse(svg.getAttribute("data-zoom"));
    var x0 = zoom.box[0], y0 = zoom.box[1], w = zoom.box[2], h = zoom.box[3];
    var lines = zoom.lines.map(function (text, i) {
      var path = svg.querySelector('[id$="-zoomline' + i + '"] path');
      return {path: path, d: path && path.getAttribute("d"), t: null, y: null};
    });
    Promise.all(zoom.lines.map(inflate)).then(function (buffers) {
      buffers.forEach(function (buffer, i) { samples(lines[i], buffer); });
      svg.setAttribute("data-zoom-ready", "");
      draw();
    });
    var xticks = Array.prototype.slice.call(svg.querySelectorAll('g[id*="-xtick_"]'));
    var label = xticks.length && xticks[0].querySelector("text");
    var axis = element("g", {"class": "zoom-ticks"});
    if (xticks.length) xticks[0].parentNode.insertBefore(axis, xticks[0]);
    var band = element("rect", {y: y0, height: h, fill: "#0969da", "fill-opacity": "0.15", visibility: "hidden"});
    svg.appendChild(band);
    var view = [0, 1], drag = null;

    function draw() {
      var whole = view[0] <= 0 && view[1] >= 1, a = view[0] * XMAX, b = view[1] * XMAX, scale = w / (b - a);
      var from = zoom.x[0] + view[0] * (zoom.x[1] - zoom.x[0]), to = zoom.x[0] + view[1] * (zoom.x[1] - zoom.x[0]);
      svg.setAttribute("data-view", from + " " + to);
      xticks.forEach(function (g) { g.style.display = whole ? "" : "none"; });
      while (axis.firstChild) axis.removeChild(axis.firstChild);
      lines.forEach(function (line) {
        if (!line.path || !line.t) return;
        if (whole) { line.path.setAttribute("d", line.d); return; }
        var t = line.t, y = line.y, end = Math.min(first(t, b) + 1, t.length), d = [], pen = "M";
        for (var i = Math.max(first(t, a) - 1, 0); i < end; i++) {
          if (y[i] === GAP) { pen = "M"; continue; }
          d.push(pen + ((t[i] - a) * scale + x0).toFixed(2) + " " + (y0 + h * (1 - y[i] / YMAX)).toFixed(2));
          pen = "L";
        }
        line.path.setAttribute("d", d.join(" "));
      });
      if (whole || !label) return;
      ticks(from, to).forEach(function (tick) {
        var x = (x0 + (tick[0] - from) / (to - from) * w).toFixed(2);
        axis.appendChild(element("path", {d: "M" + x + " " + y0 + " V" + (y0 + h), stroke: "#dddddd", "stroke-width": "0.6"}));
        axis.appendChild(element("path", {d: "M" + x + " " + (y0 + h) + " v3.5", stroke: "#000000", "stroke-width": "0.8"}));
        var text = element("text", {x: x, y: label.getAttribute("y"), style: label.getAttribute("style")});
        text.textContent = tick[1];
        axis.appendChild(text);
      });
    }

    function at(event) {                        // the pointer's x in the SVG's units, inside the data area
      var p = new DOMPoint(event.clientX, event.clientY).matrixTransform(svg.getScreenCTM().inverse());
      return {x: Math.min(Math.max(p.x, x0), x0 + w), inside: p.x >= x0 && p.x <= x0 + w && p.y >= y0 && p.y <= y0 + h};
    }

    svg.addEventListener("pointerdown", function (event) {
      var p = at(event);
      if (event.button !== 0 || !p.inside) return;
      drag = {x: p.x, pan: event.shiftKey, view: view.slice()};
      svg.setPointerCapture(event.pointerId);
      event.preventDefault();
    });
    svg.addEventListener("pointermove", function (event) {
      if (!drag) return;
      var x = at(event).x, width = drag.view[1] - drag.view[0];
      if (drag.pan) {
        var shift = Math.min(Math.max(-(x - drag.x) / w * width, -drag.view[0]), 1 - drag.view[1]);
        view = [drag.view[0] + shift, drag.view[1] + shift];
        draw();
      } else {
        band.setAttribute("x", Math.min(x, drag.x));
        band.setAttribute("width", Math.abs(x - drag.x));
        band.setAttribute("visibility", "visible");
      }
    });
    svg.addEventListener("pointerup", function (event) {
      if (!drag) return;
      var x = at(event).x, width = drag.view[1] - drag.view[0];
      band.setAttribute("visibility", "hidden");
      if (!drag.pan && Math.abs(x - drag.x) > 3 && width > 1e-6) {
        var left = (Math.min(x, drag.x) - x0) / w, right = (Math.max(x, drag.x) - x0) / w;
        view = [drag.view[0] + left * width, drag.view[0] + right * width];
        draw();
      }
      drag = null;
    });
    svg.addEventListener("dblclick", function () { view = [0, 1]; draw(); });
    svg.setAttribute("data-view", zoom.x[0] + " " + zoom.x[1]);
  }

  Array.prototype.forEach.call(document.querySelectorAll("svg.plot[data-zoom]"), function (svg) {
    setup(svg);
  });
})();
