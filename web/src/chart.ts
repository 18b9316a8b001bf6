// Time charts (uPlot) over a sliding window: bus load on the buses page,
// the selected axis's position on the axes page. Points are appended and
// drawn at most a few times a second; the window keeps the last
// `windowS` seconds. The container carries the latest figures for tests
// and tools: data-points, data-last (JSON, one value per series),
// data-min/data-max (of the first series, over the window).
import uPlot from "uplot";
import { clock } from "./api";

const COLOURS = ["#4c8df6", "#d0021b", "#2da44e", "#bf8700", "#8250df", "#57606a"];

export class TimeChart {
  private plot: uPlot | null = null;
  private xs: number[] = [];
  private ys: number[][] = [];
  private labels: string[] = [];
  private pending = false;

  constructor(
    private readonly container: HTMLElement,
    private readonly yLabel: string,
    private readonly windowS: number,
    private readonly height = 200,
  ) {
    // Also when a hidden page's chart is first shown (width 0 before).
    new ResizeObserver(() => {
      if (this.container.clientWidth > 0) this.plot?.setSize(this.size());
    }).observe(this.container);
  }

  private size(): { width: number; height: number } {
    return { width: Math.max(300, this.container.clientWidth || 800), height: this.height };
  }

  /** Sets the series (and forgets the data) when they differ from the current ones. */
  setSeries(labels: string[]): void {
    if (labels.join("\u0000") === this.labels.join("\u0000") && this.plot) return;
    this.labels = labels;
    this.xs = [];
    this.ys = labels.map(() => []);
    this.plot?.destroy();
    this.plot = new uPlot(
      {
        ...this.size(),
        scales: { x: { time: true } },
        // Times of day in 24 hours, as everywhere on the page (uPlot's
        // default is 12-hour with a date line), with tenths when the
        // ticks are less than a second apart.
        axes: [{ space: 90, values: (_u: uPlot, ticks: number[]) => timeLabels(ticks) }, { label: this.yLabel, size: 60 }],
        series: [{}, ...labels.map((label, i) => ({ label, stroke: COLOURS[i % COLOURS.length], width: 1.5 }))],
        legend: { live: false },
        cursor: { show: false },
      },
      [this.xs, ...this.ys],
      this.container,
    );
  }

  /** Appends one point per series at `t` (seconds since the epoch). */
  push(t: number, values: number[]): void {
    this.xs.push(t);
    values.forEach((v, i) => this.ys[i]?.push(v));
    let drop = 0;
    while (drop < this.xs.length && this.xs[drop] < t - this.windowS) drop++;
    if (drop > 0) {
      this.xs.splice(0, drop);
      for (const y of this.ys) y.splice(0, drop);
    }
    const first = this.ys[0] ?? [];
    const d = this.container.dataset;
    d.points = String(this.xs.length);
    d.last = JSON.stringify(values);
    d.min = String(Math.min(...first));
    d.max = String(Math.max(...first));
    if (!this.pending) {
      this.pending = true;
      requestAnimationFrame(() => {
        this.pending = false;
        this.plot?.setData([this.xs, ...this.ys]);
      });
    }
  }
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
