// Handwheels: each wheel's mode with a switch (SetMode), its feed
// statistics (frames, gaps, compensated units, repeats, bad frames,
// baselines), what its bindings did with the units, and its bindings
// (polled with ListHandwheels every second while the page is shown); and
// the live feed of every wheel (one StreamFeed stream while the page is
// shown), one line per feed frame, rendered at most once per animation
// frame.
import {
  CounterLayout,
  HandwheelMode,
  WheelAxis,
  type FeedEvent,
  type Handwheel,
} from "./gen/cangate/v1/handwheel_pb";
import { clearNotice, el, handwheels, keepStreaming, showConnected, showError } from "./api";
import { guard } from "./roles";

const enumName = (e: Record<number, string>, v: number) =>
  (e[v] ?? String(v)).toLowerCase().replace(/_/g, " ");
const AXES = ["X", "Y", "Z", "W", "V"];
const MAX_LINES = 300;
let lines: string[] = [];
let renderPending = false;

async function setMode(name: string, mode: HandwheelMode): Promise<void> {
  try {
    const w = await handwheels.setMode({ handwheel: name, mode });
    clearNotice();
    render([w], true);
  } catch (e) {
    showError(`mode of ${name}`, e);
  }
}

function card(w: Handwheel): HTMLElement {
  const modeButtons = [HandwheelMode.AUTOMATIC, HandwheelMode.MANUAL].map((m) => {
    const b = el("button", { type: "button", textContent: enumName(HandwheelMode, m) });
    b.dataset.cmd = `mode-${enumName(HandwheelMode, m)}`;
    b.addEventListener("click", () => void setMode(w.name, m));
    guard(b, "SetMode");
    return b;
  });
  const c = el(
    "section",
    { className: "card" },
    el("h3", {}, `${w.name} `, el("span", { className: "meta" }, `${w.bus} node ${w.node}, ${enumName(CounterLayout, w.counterLayout)} counter${w.simulated ? ", simulated" : ""}`)),
    el("div", { className: "cmds" }, "Mode: ", el("b", { className: "mode" }), ...modeButtons, el("span", { className: "lost" })),
    el("table", { className: "kv stats" }),
    el("table", { className: "kv binding" }),
    el("table", { className: "units" }),
    el(
      "p",
      { className: "meta" },
      w.bindings.length === 0
        ? "no bindings: the wheel only reports its feed"
        : `bindings: ${w.bindings.map((b) => `${WheelAxis[b.wheelAxis]} → ${b.axis} (${b.distancePerUnit} per unit)`).join(", ")}; at most ${w.maxUnitsPerS} units/s, stops within ${w.stopWithinMs} ms`,
    ),
  );
  c.dataset.handwheel = w.name;
  return c;
}

function kv(table: Element, rows: [string, string, bigint | number | string][]): void {
  table.replaceChildren(
    ...rows.map(([key, label, v]) => {
      const tr = el("tr", {}, el("th", {}, label), el("td", { className: "num" }, String(v)));
      tr.dataset.key = key;
      return tr;
    }),
  );
}

function update(c: HTMLElement, w: Handwheel): void {
  const mode = enumName(HandwheelMode, w.mode);
  c.querySelector(".mode")!.textContent = mode;
  c.dataset.mode = mode;
  c.querySelector(".lost")!.textContent = w.nodeLost ? "node lost (heartbeat overdue)" : "";
  const s = w.stats;
  kv(c.querySelector(".stats")!, [
    ["frames", "feed frames", s?.frames ?? 0n],
    ["gaps", "gaps (frames after lost ones)", s?.gaps ?? 0n],
    ["compensated", "compensated units", s?.compensatedUnits ?? 0n],
    ["duplicates", "repeats", s?.duplicates ?? 0n],
    ["bad", "bad frames", s?.badFrames ?? 0n],
    ["baselines", "baselines", s?.baselines ?? 0n],
    ["resets", "baseline resets", s?.baselineResets ?? 0n],
  ]);
  const b = w.binding;
  kv(c.querySelector(".binding")!, [
    ["units", "units decoded", b?.units ?? 0n],
    ["executed", "executed", b?.executedUnits ?? 0n],
    ["pending", "pending", b?.pendingUnits ?? 0n],
    ["backlog", "dropped: backlog", b?.droppedBacklog ?? 0n],
    ["not-enabled", "dropped: axis not enabled", b?.droppedNotEnabled ?? 0n],
    ["not-controlled", "dropped: axis held by another", b?.droppedNotControlled ?? 0n],
    ["unbound", "dropped: unbound", b?.droppedUnbound ?? 0n],
    ["not-manual", "dropped: not manual", b?.droppedNotManual ?? 0n],
    ["blocked", "control refused", b?.blocked || "—"],
  ]);
  c.querySelector(".units")!.replaceChildren(
    el("tr", {}, el("th", {}, "units"), ...AXES.map((a) => el("th", {}, a))),
    el("tr", {}, el("th", {}, "+"), ...AXES.map((_, i) => el("td", { className: "num" }, String(s?.positiveUnits[i] ?? 0n)))),
    el("tr", {}, el("th", {}, "−"), ...AXES.map((_, i) => el("td", { className: "num" }, String(s?.negativeUnits[i] ?? 0n)))),
  );
}

/** Shows the wheels; `partial` updates only the wheels given. */
function render(list: Handwheel[], partial = false): void {
  const box = document.getElementById("handwheels")!;
  const names = list.map((w) => w.name).join(",");
  if (!partial && box.dataset.names !== names) {
    box.dataset.names = names;
    box.replaceChildren(...list.map(card));
  }
  for (const w of list) {
    const c = box.querySelector<HTMLElement>(`section[data-handwheel="${w.name}"]`);
    if (c) update(c, w);
  }
}

function feedLine(e: FeedEvent): string {
  const t = new Date(Number(e.timestampUs / 1000n)).toISOString().slice(11, 23);
  const flags = [
    e.compensatedFlag ? `gap ${e.gap}: ${e.compensated} compensated` : "",
    e.duplicate ? "repeat" : "",
    e.baseline ? "baseline" : "",
    e.bad ? "BAD" : "",
    e.lostBefore > 0n ? `${e.lostBefore} events missed` : "",
    e.note,
  ].filter((f) => f !== "");
  const dir = e.direction > 0 ? "+" : e.direction < 0 ? "−" : " ";
  const axis = e.axis === WheelAxis.UNSPECIFIED ? "?" : WheelAxis[e.axis];
  return `${t}  ${e.handwheel}  ${axis}${dir}${e.units}  seq ${String(e.sequence).padStart(2)}  raw 0x${e.raw.toString(16).toUpperCase().padStart(2, "0")}  ${flags.join("; ")}`;
}

function scheduleRender(): void {
  if (renderPending) return;
  renderPending = true;
  requestAnimationFrame(() => {
    renderPending = false;
    const pre = document.getElementById("feed")!;
    pre.textContent = lines.join("\n");
    pre.scrollTop = pre.scrollHeight;
  });
}

/** Polls the wheels and streams their feed while the page is shown. */
export function enterHandwheels(signal: AbortSignal): void {
  const poll = async () => {
    if (signal.aborted) return;
    try {
      const r = await handwheels.listHandwheels({}, { signal });
      showConnected();
      render(r.handwheels);
    } catch (e) {
      if (signal.aborted) return;
      showError("handwheels", e);
    }
    setTimeout(poll, 1000);
  };
  void poll();
  void keepStreaming(
    "handwheel feed",
    signal,
    (sig) => handwheels.streamFeed({ handwheels: [], coalesceMs: 0 }, { signal: sig }),
    (e) => {
      lines.push(feedLine(e));
      if (lines.length > MAX_LINES) lines = lines.slice(-MAX_LINES);
      scheduleRender();
    },
  );
}
