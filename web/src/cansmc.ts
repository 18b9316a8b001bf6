// CANsmc: every master's phase, cycle and counters, its slaves with their
// DT counters and status words, the MST jitter, and the master's events,
// from one StreamCycleStats stream per master while the page is shown (the
// demo has one master; a gateway with several would hold one stream each,
// so the page shows the first master and a selector).
//
// The jitter: cansmc.proto's CycleJitter gives percentiles (p50, p99,
// p99.9, max, mean) of the MST lateness, not the histogram the gateway
// keeps (1 µs buckets); the page draws those figures as bars.
import { CansmcPhase, CansmcSlaveState, type CansmcSlave, type CansmcStatus, type CansmcEvent } from "./gen/cangate/v1/cansmc_pb";
import { cansmc, el, keepStreaming, showConnected, showError } from "./api";

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
  const k = st.counters;
  box.replaceChildren(
    el("b", { className: "phase" }, `phase ${enumName(CansmcPhase, st.phase)}`),
    ` cycle ${st.cycle}, ${st.cycleTimeUs} µs, ${st.bitrate / 1000} kbit/s, started ${st.starts}×; `,
    `overruns ${k?.overruns ?? 0n}, MDT slots missed ${k?.mdtSlotsMissed ?? 0n}, foreign frames ${k?.foreignFrames ?? 0n}, stray parameter answers ${k?.strayParameterAnswers ?? 0n}`,
    st.startError ? el("span", { className: "fault" }, ` start failed: ${st.startError}`) : "",
  );
  document.querySelector("#cansmc-slaves tbody")!.replaceChildren(...st.slaves.map(slaveRow));
  renderJitter(st);
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
  const t = new Date(Number(e.timestampUs / 1000n)).toLocaleTimeString();
  switch (e.event.case) {
    case "phase":
      return `${t}  phase ${enumName(CansmcPhase, e.event.value)}`;
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
