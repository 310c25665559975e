// A line plot of one value per frame on a 2D canvas, with marks (keyframes)
// and the player's time as a cursor.

export function drawPlot(canvas, { values, fps, marks = [], label = "" }, t) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(canvas.clientWidth, 1);
  const h = Math.max(canvas.clientHeight, 1);
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
  }
  const g = canvas.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, w, h);
  const n = values.length;
  if (!n) return;
  const pad = { l: 56, r: 12, t: 18, b: 20 };
  const max = Math.max(...values, 1e-12);
  const x = (i) => pad.l + (i / Math.max(n - 1, 1)) * (w - pad.l - pad.r);
  const y = (v) => h - pad.b - (v / max) * (h - pad.t - pad.b);
  g.strokeStyle = "#2a2f3a";
  g.beginPath();
  g.moveTo(pad.l, pad.t);
  g.lineTo(pad.l, h - pad.b);
  g.lineTo(w - pad.r, h - pad.b);
  g.stroke();
  g.strokeStyle = "rgba(78,161,255,0.35)";
  for (const k of marks) {
    g.beginPath();
    g.moveTo(x(k), pad.t);
    g.lineTo(x(k), h - pad.b);
    g.stroke();
  }
  g.strokeStyle = "#ff9f43";
  g.lineWidth = 1.5;
  g.beginPath();
  values.forEach((v, i) => (i ? g.lineTo(x(i), y(v)) : g.moveTo(x(i), y(v))));
  g.stroke();
  g.lineWidth = 1;
  const cur = Math.min(Math.floor(t * fps), n - 1);
  g.strokeStyle = "#e6e8ee";
  g.beginPath();
  g.moveTo(x(cur), pad.t);
  g.lineTo(x(cur), h - pad.b);
  g.stroke();
  g.fillStyle = "#9aa3b2";
  g.font = "11px system-ui, sans-serif";
  g.fillText(`${label} (max ${max.toExponential(2)})`, pad.l + 4, 12);
  g.fillText("0", pad.l - 12, h - pad.b);
  g.fillText(`${(n / fps).toFixed(1)} s`, w - pad.r - 34, h - 6);
  g.fillText(`frame ${cur}: ${values[cur].toExponential(2)}`, pad.l + 4, h - 6);
}
