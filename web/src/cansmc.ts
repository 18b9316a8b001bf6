// CANsmc: every master's phase, cycle and counters, its slaves with their
// DT counters and status words, the MST jitter, and the master's events,
// from one StreamCycleStats stream per master while the page is shown (the
// demo has one master; a gateway with several would hold one stream each,
// so the page shows the first master and a selector). Restart (engineer)
// and a parameter panel (ReadParameter; WriteParameter engineer) are unary
// calls.
//
// The jitter: cansmc.proto's CycleJitter gives percentiles (p50, p99,
// p99.9, max, mean) of the MST lateness, drawn as bars, and the gateway's
// histogram coarsened to at most 100 buckets (`histogram`,
// `histogram_bucket_us`), drawn on a canvas with a logarithmic count axis
// (a jitter histogram is one tall peak and a thin tail). The canvas
// carries the figures for tests and tools: data-samples, data-total (the
// sum of the bars), data-bucket-us, data-buckets, data-drawn (bars drawn).
import { CansmcPhase, CansmcSlaveState, type CansmcSlave, type CansmcStatus, type CansmcEvent } from "./gen/cangate/v1/cansmc_pb";
import { Code, ConnectError } from "@connectrpc/connect";
import { cansmc, clearNotice, clock, el, keepStreaming, showConnected, showError } from "./api";
import { guard } from "./roles";

const enumName = (e: Record<number, string>, v: number) =>
  (e[v] ?? String(v)).toLowerCase().replace(/_/g, " ");
const MAX_EVENTS = 200;
let events: string[] = [];
let selected = "";

function slaveRow(s: CansmcSlave): HTMLTableRowElement {
  const c = s.counters;
  const w = s.statusWord;
  const num = (v: bigint | number | undefined) => el("td", { className: "num" }, String(v ?? 0));
  const flags = w
    ? [w.ready && "ready", w.enabled && "enabled", w.fault && "FAULT", w.targetReached && "in position", w.homed && "homed", w.followingError && "FOLLOWING ERROR", w.parameterError && "parameter error"]
        .filter((f): f is string => typeof f === "string")
        .join(", ")
    : "";
  const tr = el(
    "tr",
    {},
    el("td", { className: "num" }, String(s.address)),
    el("td", {}, s.name + (s.required ? "" : " (optional)")),
    el("td", { className: "state" }, enumName(CansmcSlaveState, s.state)),
    el("td", {}, s.axis || "—"),
    num(c?.dts),
    num(c?.missed),
    num(c?.late),
    num(c?.counterMismatch),
    num(c?.rejects),
    num(c?.malformed),
    num(c?.losses),
    num(s.consecutiveMisses),
    el("td", {}, w ? `0x${w.raw.toString(16).toUpperCase().padStart(4, "0")} ${flags}` : "—"),
  );
  tr.dataset.address = String(s.address);
  tr.dataset.state = enumName(CansmcSlaveState, s.state);
  tr.dataset.dts = String(c?.dts ?? 0n);
  return tr;
}

function renderStatus(st: CansmcStatus): void {
  const box = document.getElementById("cansmc-master")!;
  box.dataset.phase = enumName(CansmcPhase, st.phase);
  box.dataset.starts = String(st.starts);
  const k = st.counters;
  box.replaceChildren(
    el("b", { className: "phase" }, `phase ${enumName(CansmcPhase, st.phase).toUpperCase()}`),
    ` cycle ${st.cycle}, ${st.cycleTimeUs} µs, ${st.bitrate / 1000} kbit/s, started ${st.starts}×; `,
    `overruns ${k?.overruns ?? 0n}, MDT slots missed ${k?.mdtSlotsMissed ?? 0n}, foreign frames ${k?.foreignFrames ?? 0n}, stray parameter answers ${k?.strayParameterAnswers ?? 0n}`,
    st.startError ? el("span", { className: "fault" }, ` start failed: ${st.startError}`) : "",
  );
  document.querySelector("#cansmc-slaves tbody")!.replaceChildren(...st.slaves.map(slaveRow));
  paramSlaves(st.slaves);
  renderJitter(st);
  drawHistogram(st);
}

/** The parameter panel's slave choice follows the master's slaves. */
function paramSlaves(slaves: CansmcSlave[]): void {
  const select = document.getElementById("param-slave") as HTMLSelectElement;
  const keys = slaves.map((s) => `${s.address}:${s.name}`).join(",");
  if (select.dataset.keys === keys) return;
  select.dataset.keys = keys;
  const before = select.value;
  select.replaceChildren(
    ...slaves.map((s) => el("option", { value: String(s.address) }, `${s.address}${s.name ? ` ${s.name}` : ""}`)),
  );
  if (slaves.some((s) => String(s.address) === before)) select.value = before;
}

/** The MST lateness histogram on its canvas: bars of `histogram_bucket_us`, log counts. */
function drawHistogram(st: CansmcStatus): void {
  const canvas = document.getElementById("cansmc-histogram") as HTMLCanvasElement;
  const j = st.jitter;
  const counts = (j?.histogram ?? []).map(Number);
  const width = j?.histogramBucketUs ?? 1;
  const d = canvas.dataset;
  d.samples = String(j?.samples ?? 0n);
  d.total = String((j?.histogram ?? []).reduce((a, b) => a + b, 0n));
  d.bucketUs = String(width);
  d.buckets = String(counts.length);
  const w = Math.max(300, canvas.parentElement?.clientWidth ?? 400);
  const h = 160;
  const dpr = window.devicePixelRatio || 1;
  if (canvas.width !== Math.round(w * dpr)) {
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
    canvas.style.width = `${w}px`;
    canvas.style.height = `${h}px`;
  }
  const g = canvas.getContext("2d")!;
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, w, h);
  g.font = "11px system-ui, sans-serif";
  g.fillStyle = "#57606a";
  const left = 8;
  const bottom = h - 18;
  const top = 14;
  // Always 100 slots wide, so the bars keep their width as buckets come.
  const slot = (w - 2 * left) / 100;
  const peak = Math.max(1, ...counts);
  const scale = (bottom - top) / Math.log10(peak + 1);
  let drawn = 0;
  g.fillStyle = "#4c8df6";
  counts.forEach((n, i) => {
    if (n === 0) return;
    const bh = Math.max(1, Math.log10(n + 1) * scale);
    g.fillRect(left + i * slot, bottom - bh, Math.max(1, slot - 1), bh);
    drawn++;
  });
  d.drawn = String(drawn);
  g.fillStyle = "#57606a";
  g.fillRect(left, bottom, w - 2 * left, 1);
  g.textBaseline = "top";
  for (const i of [0, 25, 50, 75, 100]) {
    const label = i === 100 ? `${100 * width} µs` : `${i * width}`;
    g.textAlign = i === 0 ? "left" : i === 100 ? "right" : "center";
    g.fillText(label, left + i * slot, bottom + 3);
  }
  g.textAlign = "left";
  g.textBaseline = "alphabetic";
  g.fillText(
    counts.length === 0
      ? "no cycles measured yet"
      : `MSTs per ${width} µs of lateness (log scale, peak ${peak}); the last bar counts every later MST`,
    left,
    11,
  );
}

function renderJitter(st: CansmcStatus): void {
  const j = st.jitter;
  const box = document.getElementById("cansmc-jitter")!;
  if (!j || j.samples === 0n) {
    box.replaceChildren(el("p", { className: "meta" }, "no cycles measured yet"));
    return;
  }
  const bars: [string, number][] = [
    ["mean", j.meanUs],
    ["p50", j.p50Us],
    ["p99", j.p99Us],
    ["p99.9", j.p999Us],
    ["max", j.maxUs],
  ];
  // A logarithmic scale up to one cycle: a late MST of a whole cycle is
  // an overrun.
  const full = Math.log10(Math.max(st.cycleTimeUs, j.maxUs, 10) + 1);
  box.replaceChildren(
    el("p", { className: "meta" }, `MST lateness over ${j.samples} cycles (µs, log scale up to one cycle of ${st.cycleTimeUs} µs)`),
    ...bars.map(([label, us]) => {
      const bar = el("div", { className: "bar" });
      bar.style.width = `${(100 * Math.log10(us + 1)) / full}%`;
      const row = el("div", { className: "jrow" }, el("span", { className: "jl" }, label), el("div", { className: "track" }, bar), el("span", { className: "num jv" }, us.toFixed(1)));
      row.dataset.stat = label;
      row.dataset.us = String(us);
      return row;
    }),
  );
}

function eventLine(e: CansmcEvent): string {
  const t = clock(Number(e.timestampUs / 1000n));
  switch (e.event.case) {
    case "phase":
      return `${t}  phase ${enumName(CansmcPhase, e.event.value).toUpperCase()}`;
    case "slave":
      return `${t}  slave ${e.event.value.address}: ${e.event.value.what}`;
    default:
      return `${t}  unknown event`;
  }
}

function logEvents(lines: string[]): void {
  if (lines.length === 0) return;
  events.push(...lines);
  if (events.length > MAX_EVENTS) events = events.slice(-MAX_EVENTS);
  const pre = document.getElementById("cansmc-events")!;
  pre.textContent = events.join("\n");
  pre.scrollTop = pre.scrollHeight;
}

function openStream(signal: AbortSignal, master: string): void {
  events = [];
  void keepStreaming(
    "CANsmc cycle stats",
    signal,
    (sig) => cansmc.streamCycleStats({ master, intervalMs: 500 }, { signal: sig }),
    (u) => {
      if (u.status) renderStatus(u.status);
      const lines = u.events.map(eventLine);
      if (u.eventsLost > 0n) lines.push(`${u.eventsLost} events missed (read too slowly)`);
      logEvents(lines);
    },
  );
}

// ---- Restart and parameters ----

let restartArmed: ReturnType<typeof setTimeout> | undefined;

/** Restart asks once more (the button turns into "Confirm restart" for 3 s). */
async function restart(button: HTMLButtonElement): Promise<void> {
  if (restartArmed === undefined) {
    button.textContent = "Confirm restart";
    button.dataset.armed = "true";
    restartArmed = setTimeout(disarm, 3000);
    return;
  }
  disarm();
  try {
    const r = await cansmc.restart({ master: selected });
    clearNotice();
    logEvents([`${clock()}  restart of ${r.master} requested`]);
  } catch (e) {
    showError(`Restart of ${selected || "the master"}`, e);
  }
  function disarm(): void {
    clearTimeout(restartArmed);
    restartArmed = undefined;
    button.textContent = "Restart";
    delete button.dataset.armed;
  }
}

function showParam(ok: boolean, text: string): void {
  const out = document.getElementById("param-result")!;
  out.textContent = text;
  out.className = ok ? "sdo-result sdo-ok" : "sdo-result sdo-error";
  out.dataset.outcome = ok ? "ok" : "error";
}

/** The panel's slave and parameter number, or why they are not valid. */
function paramTarget(): { address: number; number: number } | string {
  const address = Number((document.getElementById("param-slave") as HTMLSelectElement).value);
  const text = (document.getElementById("param-number") as HTMLInputElement).value.trim();
  const number = /^0x/i.test(text) ? Number.parseInt(text.slice(2), 16) : Number(text);
  if (!(address >= 1)) return "no slave selected";
  if (!(Number.isInteger(number) && number >= 0 && number <= 0xffff)) return "parameter number: 0 to 65535 (or 0x..)";
  return { address, number };
}

async function parameter(write: boolean): Promise<void> {
  const t = paramTarget();
  if (typeof t === "string") return showParam(false, t);
  const what = `${write ? "write" : "read"} slave ${t.address} parameter ${t.number}`;
  try {
    let r;
    if (write) {
      const text = (document.getElementById("param-value") as HTMLInputElement).value.trim();
      const value = Number(text);
      if (text === "" || !Number.isInteger(value) || value < -(2 ** 31) || value >= 2 ** 31) {
        return showParam(false, `${what}: the value is a 32-bit signed integer`);
      }
      r = await cansmc.writeParameter({ master: selected, ...t, value });
    } else {
      r = await cansmc.readParameter({ master: selected, ...t });
    }
    (document.getElementById("param-value") as HTMLInputElement).value = String(r.value);
    const out = document.getElementById("param-result")!;
    showParam(true, `${what}: ${r.value}${write ? " (confirmed by the slave)" : ""}`);
    out.dataset.value = String(r.value);
  } catch (e) {
    const err = ConnectError.from(e);
    if (err.code === Code.PermissionDenied || err.code === Code.Unauthenticated) showError(what, e);
    showParam(false, `${what}: ${Code[err.code]}: ${err.rawMessage}`);
  }
}

/** The page's buttons, once. */
export function initCansmc(): void {
  const restartButton = document.getElementById("cansmc-restart") as HTMLButtonElement;
  restartButton.addEventListener("click", () => void restart(restartButton));
  guard(restartButton, "Restart");
  const read = document.getElementById("param-read") as HTMLButtonElement;
  const write = document.getElementById("param-write") as HTMLButtonElement;
  read.addEventListener("click", () => void parameter(false));
  write.addEventListener("click", () => void parameter(true));
  guard(read, "ReadParameter");
  guard(write, "WriteParameter");
  document.getElementById("param-form")!.addEventListener("submit", (e) => {
    e.preventDefault();
    void parameter(false);
  });
}

/** Lists the masters and streams the selected one's state while the page is shown. */
export function enterCansmc(signal: AbortSignal): void {
  void (async () => {
    try {
      const r = await cansmc.listMasters({}, { signal });
      showConnected();
      const select = document.getElementById("cansmc-select") as HTMLSelectElement;
      select.replaceChildren(
        ...r.masters.map((m) => el("option", { value: m.name }, `${m.name} (${m.commandBus}/${m.statusBus})`)),
      );
      if (r.masters.length === 0) {
        document.getElementById("cansmc-master")!.textContent = "no CANsmc master configured";
        return;
      }
      if (!r.masters.some((m) => m.name === selected)) selected = r.masters[0].name;
      select.value = selected;
      let ctl = new AbortController();
      signal.addEventListener("abort", () => ctl.abort(), { once: true });
      select.onchange = () => {
        ctl.abort();
        ctl = new AbortController();
        signal.addEventListener("abort", () => ctl.abort(), { once: true });
        selected = select.value;
        openStream(ctl.signal, selected);
      };
      openStream(ctl.signal, selected);
    } catch (e) {
      if (!signal.aborted) showError("CANsmc masters", e);
    }
  })();
}
