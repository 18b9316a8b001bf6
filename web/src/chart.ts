// Time charts on a plain canvas over a sliding window: bus load on the
// buses page, the selected axis's position on the axes page. Points are
// appended as they come; the chart is drawn at most `maxHz` times a second
// and only while it is on the screen (a hidden page's chart has no size:
// its ResizeObserver says when it is shown again). The window keeps the
// last `windowS` seconds. The container carries the drawn figures for
// tests and tools: data-points, data-last (JSON, one value per series),
// data-min/data-max (of the first series, over the window).
import { clock } from "./api";

const COLOURS = ["#4c8df6", "#d0021b", "#2da44e", "#bf8700", "#8250df", "#57606a"];
/** Room around the plot, CSS pixels: tick labels left and below, the legend above. */
const PAD = { left: 64, right: 12, top: 22, bottom: 24 };
/** Time steps the ticks may take, seconds. */
const TIME_STEPS = [0.1, 0.2, 0.5, 1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 1800, 3600];
/** Least room between two time labels, CSS pixels (`HH:MM:SS.t` is about 70). */
const TIME_TICK_PX = 90;
/** Least room between two value labels, CSS pixels. */
const VALUE_TICK_PX = 30;

export class TimeChart {
  private readonly canvas: HTMLCanvasElement;
  private xs: number[] = [];
  private ys: number[][] = [];
  private labels: string[] = [];
  private last: number[] = [];
  /** The canvas's size in CSS pixels; width 0 while the chart is hidden. */
  private width = 0;
  private drawTimer = 0;
  private lastDraw = 0;

  constructor(
    private readonly container: HTMLElement,
    private readonly yLabel: string,
    private readonly windowS: number,
    private readonly height = 200,
    private readonly maxHz = 10,
  ) {
    this.canvas = document.createElement("canvas");
    this.canvas.style.display = "block";
    this.container.append(this.canvas);
    // Called after layout with the new size: no layout is read while
    // drawing. A page shown again has its chart drawn at once.
    new ResizeObserver((entries) => {
      const width = Math.floor(entries[entries.length - 1].contentRect.width);
      if (width === this.width) return;
      this.width = width;
      if (width > 0) this.draw();
    }).observe(this.container);
  }

  /** Sets the series (and forgets the data) when they differ from the current ones. */
  setSeries(labels: string[]): void {
    if (labels.join("\u0000") === this.labels.join("\u0000")) return;
    this.labels = labels;
    this.xs = [];
    this.ys = labels.map(() => []);
    this.last = [];
    this.schedule();
  }

  /** Appends one point per series at `t` (seconds since the epoch). */
  push(t: number, values: number[]): void {
    this.xs.push(t);
    values.forEach((v, i) => this.ys[i]?.push(v));
    this.last = values;
    // Dropped in chunks: a shift per point would move the whole window.
    if (this.xs[0] < t - this.windowS * 1.1) {
      let drop = 0;
      while (drop < this.xs.length && this.xs[drop] < t - this.windowS) drop++;
      this.xs.splice(0, drop);
      for (const y of this.ys) y.splice(0, drop);
    }
    this.schedule();
  }

  /** Draws at the next animation frame, at most `maxHz` times a second, while shown. */
  private schedule(): void {
    if (this.drawTimer !== 0 || this.width === 0) return;
    const wait = Math.max(0, this.lastDraw + 1000 / this.maxHz - performance.now());
    this.drawTimer = window.setTimeout(() => requestAnimationFrame(() => this.draw()), wait);
  }

  private draw(): void {
    clearTimeout(this.drawTimer);
    this.drawTimer = 0;
    if (this.width === 0) return;
    this.lastDraw = performance.now();
    const { xs, ys } = this;
    const now = xs.length > 0 ? xs[xs.length - 1] : Date.now() / 1000;
    let from = 0;
    while (from < xs.length && xs[from] < now - this.windowS) from++;
    const first = ys[0] ?? [];
    let lo = Infinity;
    let hi = -Infinity;
    for (let i = from; i < first.length; i++) {
      lo = Math.min(lo, first[i]);
      hi = Math.max(hi, first[i]);
    }
    const d = this.container.dataset;
    d.points = String(xs.length - from);
    d.last = JSON.stringify(this.last);
    d.min = String(lo);
    d.max = String(hi);
    // The value axis spans every series.
    for (const y of ys.slice(1)) {
      for (let i = from; i < y.length; i++) {
        lo = Math.min(lo, y[i]);
        hi = Math.max(hi, y[i]);
      }
    }
    this.paint(from, lo, hi);
  }

  private paint(from: number, lo: number, hi: number): void {
    const dpr = window.devicePixelRatio || 1;
    const w = this.width;
    const h = this.height;
    const c = this.canvas;
    if (c.width !== Math.round(w * dpr) || c.height !== Math.round(h * dpr)) {
      c.width = Math.round(w * dpr);
      c.height = Math.round(h * dpr);
      c.style.width = `${w}px`;
      c.style.height = `${h}px`;
    }
    const g = c.getContext("2d")!;
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, h);
    g.font = "12px system-ui, sans-serif";
    const plot = { x: PAD.left, y: PAD.top, w: Math.max(10, w - PAD.left - PAD.right), h: Math.max(10, h - PAD.top - PAD.bottom) };

    // The legend: each series's colour and label.
    let lx = plot.x;
    this.labels.forEach((label, i) => {
      g.fillStyle = COLOURS[i % COLOURS.length];
      g.fillRect(lx, 6, 14, 3);
      g.fillStyle = "#1b1f24";
      g.textBaseline = "middle";
      g.textAlign = "left";
      g.fillText(label, lx + 18, 8);
      lx += 18 + g.measureText(label).width + 16;
    });

    const xs = this.xs;
    const t1 = xs.length > 0 ? xs[xs.length - 1] : Date.now() / 1000;
    const t0 = xs.length > from ? Math.min(xs[from], t1 - 1) : t1 - this.windowS;
    if (!Number.isFinite(lo)) {
      lo = 0;
      hi = 1;
    }
    if (hi - lo < 1e-9) {
      const pad = Math.max(Math.abs(hi) * 0.05, 0.5);
      lo -= pad;
      hi += pad;
    }
    const vTicks = niceTicks(lo, hi, Math.max(2, Math.floor(plot.h / VALUE_TICK_PX)));
    lo = Math.min(lo, vTicks[0]);
    hi = Math.max(hi, vTicks[vTicks.length - 1]);
    const px = (t: number) => plot.x + ((t - t0) / (t1 - t0)) * plot.w;
    const py = (v: number) => plot.y + plot.h - ((v - lo) / (hi - lo)) * plot.h;

    // Grid and value labels.
    g.strokeStyle = "#e3e6ea";
    g.lineWidth = 1;
    g.fillStyle = "#57606a";
    g.textAlign = "right";
    g.textBaseline = "middle";
    g.beginPath();
    const decimals = tickDecimals(vTicks);
    for (const v of vTicks) {
      const y = Math.round(py(v)) + 0.5;
      g.moveTo(plot.x, y);
      g.lineTo(plot.x + plot.w, y);
      g.fillText(v.toFixed(decimals), plot.x - 6, y);
    }
    // Time labels: 24-hour times of day, as everywhere on the page.
    const span = t1 - t0;
    const step = TIME_STEPS.find((s) => (s / span) * plot.w >= TIME_TICK_PX) ?? TIME_STEPS[TIME_STEPS.length - 1];
    const ticks: number[] = [];
    for (let k = Math.ceil(t0 / step); k * step <= t1; k++) ticks.push(k * step);
    g.textAlign = "center";
    g.textBaseline = "top";
    timeLabels(ticks).forEach((label, i) => {
      const x = Math.round(px(ticks[i])) + 0.5;
      g.moveTo(x, plot.y);
      g.lineTo(x, plot.y + plot.h);
      g.fillText(label, x, plot.y + plot.h + 6);
    });
    g.stroke();

    // The value axis's name, upright at the left.
    g.save();
    g.translate(12, plot.y + plot.h / 2);
    g.rotate(-Math.PI / 2);
    g.textAlign = "center";
    g.textBaseline = "middle";
    g.fillText(this.yLabel, 0, 0);
    g.restore();

    // The series, clipped to the plot.
    g.save();
    g.beginPath();
    g.rect(plot.x, plot.y, plot.w, plot.h);
    g.clip();
    g.lineWidth = 1.5;
    g.lineJoin = "round";
    this.ys.forEach((y, s) => {
      g.strokeStyle = COLOURS[s % COLOURS.length];
      g.beginPath();
      for (let i = from; i < y.length; i++) {
        if (i === from) g.moveTo(px(xs[i]), py(y[i]));
        else g.lineTo(px(xs[i]), py(y[i]));
      }
      g.stroke();
    });
    g.restore();
  }
}

/** Round tick values (1, 2 or 5 × 10ⁿ apart) covering `lo`..`hi`, about `count` of them. */
export function niceTicks(lo: number, hi: number, count: number): number[] {
  const raw = (hi - lo) / Math.max(1, count);
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw) ?? 10 * mag;
  const out: number[] = [];
  const start = Math.floor(lo / step);
  for (let k = start; ; k++) {
    const v = k * step;
    out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
    if (v >= hi - step * 1e-9 || out.length > 100) break;
  }
  return out;
}

/** Decimals that tell the ticks apart. */
function tickDecimals(ticks: number[]): number {
  const step = ticks.length > 1 ? Math.abs(ticks[1] - ticks[0]) : 1;
  return Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9)));
}

/** Tick labels for times (seconds since the epoch): `HH:MM:SS`, with
 * tenths when the ticks are closer than a second. */
export function timeLabels(ticks: number[]): string[] {
  const step = ticks.length > 1 ? ticks[1] - ticks[0] : 1;
  return ticks.map((t) => {
    const ms = Math.round(t * 1000);
    return step < 1 ? `${clock(ms)}.${Math.floor((ms % 1000) / 100)}` : clock(ms);
  });
}
