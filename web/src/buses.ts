// Buses: state and counters (polled every second; the load % charted
// over the last five minutes), and a live frame view of one bus
// (one server stream, while the page is shown) that coalesces rendering to animation frames, shows
// the rate, can pause, and shows frames the gateway reports lost.
import { create } from "@bufbuild/protobuf";
import { BusState, FrameFilterSchema, IdFormat, type BusInfo, type Frame, type FrameFilter } from "./gen/cangate/v1/bus_pb";
import { backoff, bus, el, keepStreaming, showConnected, showError } from "./api";
import { TimeChart } from "./chart";

/** Bound of each poll of the buses, the page's heartbeat. */
const POLL_TIMEOUT_MS = 1500;

const MAX_LINES = 500;
let lines: string[] = [];
let received = 0;
let lost = 0n;
let paused = false;
let renderPending = false;
let selected = "";
let streamAbort: AbortController | null = null;
let parent: AbortSignal | null = null;
let loadChart: TimeChart | null = null;
let filters: FrameFilter[] = [];
/** The buses page is shown: its table and view are drawn. */
let shown = false;
/** The latest poll's buses, drawn when the page is shown. */
let latest: BusInfo[] = [];
/** Lines received since the view was last drawn. */
let fresh = 0;
/** Lines the view's box shows (from its height and line height). */
let visibleLines = 30;

/**
 * candump-style filters, comma or space separated: `ID:MASK` passes a
 * frame when (frame id & MASK) == (ID & MASK), `ID~MASK` when it does not;
 * a frame passes if any filter passes it. Hex; an ID of up to 3 digits is
 * a standard (11-bit) filter, more digits an extended (29-bit) one, as
 * candump reads them. The gateway applies them (StreamFrames filters), so
 * filtered-out frames never reach the page. candump's error-frame filter
 * (`#MASK`) and `j` (join) are not supported.
 */
export function parseFilters(text: string): FrameFilter[] | string {
  const out: FrameFilter[] = [];
  for (const part of text.split(/[\s,]+/).filter((p) => p !== "")) {
    const m = /^([0-9a-fA-F]{1,8})([:~])([0-9a-fA-F]{1,8})$/.exec(part);
    if (!m) return `"${part}": not ID:MASK or ID~MASK (hex), e.g. 123:7FF or 18FF0000~1FFF0000`;
    const id = Number.parseInt(m[1], 16);
    const mask = Number.parseInt(m[3], 16);
    const extended = m[1].length > 3;
    if (id > 0x1fffffff || mask > 0x1fffffff) return `"${part}": more than 29 bits`;
    out.push(
      create(FrameFilterSchema, {
        id,
        mask,
        format: extended ? IdFormat.EXTENDED : IdFormat.STANDARD,
        invert: m[2] === "~",
      }),
    );
  }
  return out;
}

function hex(n: number, width: number): string {
  return n.toString(16).toUpperCase().padStart(width, "0");
}

/** A frame as candump prints it: `can0  123   [2]  DE AD`. */
export function candump(name: string, f: Frame): string {
  const id = f.extended ? hex(f.id, 8) : hex(f.id, 3).padEnd(8, " ");
  if (f.remote) return `${name}  ${id}   [${f.remoteDlc}]  remote request`;
  const len = f.fd ? `[${String(f.data.length).padStart(2, "0")}]` : `[${f.data.length}]`;
  const data = Array.from(f.data, (b) => hex(b, 2)).join(" ");
  return `${name}  ${id}   ${len}  ${data}`;
}

/** Lines drawn at most while the view follows the bus: more than a full
 * 1 Mbit/s bus brings between two animation frames (~140 at 8,000
 * frames/s), twice over, for an animation frame that comes late on a
 * busy host. Laying out all MAX_LINES at every animation frame cost the
 * page half a core of this machine's CPU; paused, the view draws them all,
 * for scrolling back. */
const LIVE_LINES = 300;

/**
 * Draws the view. Following the bus it draws the lines its box shows, or
 * more when more came since the last drawing, so that no frame skips the
 * screen: at demo traffic a few dozen lines are laid out per animation
 * frame instead of LIVE_LINES.
 */
function render(): void {
  renderPending = false;
  const pre = document.getElementById("frames")!;
  const live = Math.min(LIVE_LINES, Math.max(visibleLines, fresh));
  fresh = 0;
  pre.textContent = (paused ? lines : lines.slice(-live)).join("\n");
  pre.scrollTop = pre.scrollHeight;
}

function scheduleRender(): void {
  if (renderPending || paused || !shown) return;
  renderPending = true;
  requestAnimationFrame(render);
}

function openFrames(): void {
  streamAbort?.abort();
  if (!parent || parent.aborted || !selected) return;
  const ctl = new AbortController();
  parent.addEventListener("abort", () => ctl.abort(), { once: true });
  streamAbort = ctl;
  lines = [];
  scheduleRender();
  lost = 0n;
  document.getElementById("frames-lost")!.hidden = true;
  const name = selected;
  void keepStreaming(
    "frame stream",
    ctl.signal,
    (signal) => bus.streamFrames({ bus: name, queueLength: 0, filters }, { signal }),
    (m) => {
      for (const ev of m.events) {
        if (ev.event.case === "frame") {
          received++;
          if (!paused) {
            lines.push(candump(name, ev.event.value));
            fresh++;
          }
        } else if (ev.event.case === "lost") {
          lost += ev.event.value.count;
          const l = document.getElementById("frames-lost")!;
          l.textContent = `${lost} frames lost`;
          l.hidden = false;
        }
      }
      if (lines.length > MAX_LINES) lines = lines.slice(-MAX_LINES);
      scheduleRender();
    },
  );
}

function stateName(b: BusInfo): string {
  const s = b.status?.state ?? BusState.UNSPECIFIED;
  return (BusState[s] ?? String(s)).toLowerCase().replace(/_/g, " ");
}

function renderTable(list: BusInfo[]): void {
  loadChart?.setSeries(list.map((b) => b.name));
  loadChart?.push(Date.now() / 1000, list.map((b) => b.statistics?.loadPercent ?? 0));
  latest = list;
  if (shown) drawTable(list);
  const select = document.getElementById("frame-bus") as HTMLSelectElement;
  if (select.options.length !== list.length) {
    select.replaceChildren(...list.map((b) => el("option", { value: b.name }, b.name)));
    if (!selected && list.length > 0) {
      selected = list[0].name;
      select.value = selected;
      openFrames();
    }
  }
}

/** The buses' table (while the page is shown). */
function drawTable(list: BusInfo[]): void {
  const tbody = document.querySelector("#buses tbody")!;
  tbody.replaceChildren(
    ...list.map((b) => {
      const st = b.statistics;
      const num = (v: bigint | number | undefined) => el("td", { className: "num" }, String(v ?? 0));
      const row = el(
        "tr",
        {},
        el("td", {}, b.name),
        el("td", { className: "state" }, stateName(b)),
        el("td", { className: "num" }, (st?.loadPercent ?? 0).toFixed(1)),
        num(st?.rxFrames),
        num(st?.txFrames),
        num(b.status?.txErrors),
        num(b.status?.rxErrors),
        num(st?.errorFrames),
        num(st?.subscriberDrops),
      );
      row.dataset.bus = b.name;
      return row;
    }),
  );
}

/** Streams the selected bus's frames, and draws the page, while it is shown. */
export function enterBuses(signal: AbortSignal): void {
  parent = signal;
  shown = true;
  signal.addEventListener(
    "abort",
    () => {
      shown = false;
    },
    { once: true },
  );
  drawTable(latest);
  openFrames();
}

/** Starts polling the buses until `signal` aborts. */
export function startBuses(signal: AbortSignal): void {
  selected = "";
  (document.getElementById("frame-bus") as HTMLSelectElement).replaceChildren();
  // Also the page's heartbeat (see "the link" in api.ts): each call is
  // bounded, so a gateway that stops answering is lost within about two
  // seconds and a half; failing, the poll backs off.
  let failures = 0;
  const poll = async () => {
    if (signal.aborted) return;
    try {
      const r = await bus.listBuses({}, { signal, timeoutMs: POLL_TIMEOUT_MS });
      showConnected();
      failures = 0;
      renderTable(r.buses);
    } catch (e) {
      if (signal.aborted) return;
      failures += 1;
      showError("buses", e);
    }
    setTimeout(poll, failures === 0 ? 1000 : Math.min(backoff(failures + 1), 4000));
  };
  void poll();
}

export function initBuses(): void {
  loadChart = new TimeChart(document.getElementById("load-chart")!, "load %", 300);
  const select = document.getElementById("frame-bus") as HTMLSelectElement;
  select.addEventListener("change", () => {
    selected = select.value;
    openFrames();
  });
  const filter = document.getElementById("frames-filter") as HTMLInputElement;
  filter.addEventListener("change", () => {
    const f = parseFilters(filter.value);
    const bad = document.getElementById("frames-filter-error")!;
    bad.textContent = typeof f === "string" ? f : "";
    bad.hidden = typeof f !== "string";
    if (typeof f === "string") return;
    filters = f;
    filter.dataset.applied = filter.value;
    openFrames();
  });
  const pause = document.getElementById("frames-pause")!;
  pause.addEventListener("click", () => {
    paused = !paused;
    pause.textContent = paused ? "Resume" : "Pause";
    // Paused: every kept line at once, to scroll back; resumed: the tail.
    if (paused) render();
    else scheduleRender();
  });
  // The view's height in lines, after each layout that changed it.
  const pre = document.getElementById("frames")!;
  new ResizeObserver(() => {
    const lineHeight = Number.parseFloat(getComputedStyle(pre).lineHeight) || 15;
    if (pre.clientHeight > 0) visibleLines = Math.ceil(pre.clientHeight / lineHeight) + 1;
  }).observe(pre);
  let last = 0;
  setInterval(() => {
    if (shown) document.getElementById("frames-rate")!.textContent = `${received - last} frames/s`;
    last = received;
  }, 1000);
}
