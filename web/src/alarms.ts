// Alarms: what needs the operator's attention, across the gateway, in one
// list with time, source and text, each kept until acknowledged. The count
// of unacknowledged alarms is in the header on every page.
//
// Sources: the CANopen nodes' events (EMCY, heartbeat lost, boot failed,
// node guarding errors, events missed), from one node-event stream that
// the page keeps open for as long as it runs (the CANopen page's event log
// shares it), and the axes' events (a fault, a drive's node lost: a CANsmc
// slave lost too, the following error and limit switches as the drives
// report them) and the page's own lost leases, handed in by axes.ts.
//
// An alarm whose condition went away (the heartbeat back, an EMCY reset,
// the node back) is marked cleared but stays until acknowledged: the
// operator sees that it happened.
import { bus, canopen, cansmc, clock, el, keepStreaming } from "./api";
import { eventText } from "./events";
import { BusState } from "./gen/cangate/v1/bus_pb";
import type { NodeEvent } from "./gen/cangate/v1/canopen_pb";
import { CansmcSlaveState } from "./gen/cangate/v1/cansmc_pb";

export interface Alarm {
  id: number;
  /** When it was raised (ms since the epoch). */
  at: number;
  /** What raised it: "can0 node 4", "axis X". */
  source: string;
  text: string;
  /** The condition is gone. */
  cleared: boolean;
  acknowledged: boolean;
}

/** Alarms kept at most (the oldest acknowledged go first). */
const MAX_ALARMS = 200;
const alarms: Alarm[] = [];
let nextId = 1;
const nodeListeners = new Set<(ev: NodeEvent) => void>();

/** Raises an alarm (the same text from the same source, still active and
 * not acknowledged, is raised once). */
export function raise(source: string, text: string, at = Date.now()): void {
  if (alarms.some((a) => a.source === source && a.text === text && !a.cleared && !a.acknowledged)) return;
  alarms.unshift({ id: nextId++, at, source, text, cleared: false, acknowledged: false });
  while (alarms.length > MAX_ALARMS) {
    const old = alarms.map((a) => a.acknowledged).lastIndexOf(true);
    alarms.splice(old >= 0 ? old : alarms.length - 1, 1);
  }
  render();
}

/** The condition behind `source`'s alarms (those `match` picks) is gone. */
export function clear(source: string, match: (text: string) => boolean = () => true): void {
  let changed = false;
  for (const a of alarms) {
    if (a.source === source && !a.cleared && match(a.text)) {
      a.cleared = true;
      changed = true;
    }
  }
  if (changed) render();
}

function acknowledge(ids: number[]): void {
  for (const a of alarms) if (ids.includes(a.id)) a.acknowledged = true;
  render();
}

/** Unacknowledged alarms. */
export function activeCount(): number {
  return alarms.filter((a) => !a.acknowledged).length;
}

function render(): void {
  const count = activeCount();
  const badge = document.getElementById("alarm-count");
  if (badge) {
    badge.textContent = String(count);
    badge.hidden = count === 0;
    badge.dataset.count = String(count);
  }
  const tbody = document.querySelector("#alarms tbody");
  if (!tbody) return;
  tbody.replaceChildren(
    ...alarms.map((a) => {
      const ack = el("button", { type: "button", textContent: "Acknowledge" });
      ack.dataset.cmd = "acknowledge";
      ack.hidden = a.acknowledged;
      ack.addEventListener("click", () => acknowledge([a.id]));
      const state = a.acknowledged ? (a.cleared ? "acknowledged, cleared" : "acknowledged") : a.cleared ? "cleared" : "active";
      const tr = el(
        "tr",
        { className: a.acknowledged ? "acked" : a.cleared ? "cleared" : "active" },
        el("td", { className: "time" }, clock(a.at)),
        el("td", { className: "source" }, a.source),
        el("td", { className: "text" }, a.text),
        el("td", { className: "state" }, state),
        el("td", {}, ack),
      );
      tr.dataset.source = a.source;
      tr.dataset.state = state;
      return tr;
    }),
  );
}

/** Listens to the node-event stream (the CANopen page's log); returns the
 * function that stops listening. */
export function onNodeEvent(listener: (ev: NodeEvent) => void): () => void {
  nodeListeners.add(listener);
  return () => nodeListeners.delete(listener);
}

function nodeAlarm(ev: NodeEvent): void {
  const source = `${ev.bus} node ${ev.node}`;
  const at = Number(ev.timestampNs / 1_000_000n) || Date.now();
  const e = ev.event;
  switch (e.case) {
    case "emcy":
      // Error code 0: the device reset its errors.
      if (e.value.code === 0) clear(source, (t) => t.startsWith("EMCY"));
      else raise(source, eventText(ev), at);
      break;
    case "heartbeatLost":
    case "bootFailed":
    case "guardingToggleError":
      raise(source, eventText(ev), at);
      break;
    case "lost":
      raise("gateway", `node events: ${eventText(ev)}`, at);
      break;
    case "heartbeatRecovered":
      clear(source, (t) => t.startsWith("heartbeat lost"));
      break;
    case "bootCompleted":
      clear(source, (t) => t.startsWith("boot procedure failed"));
      break;
    default:
      break;
  }
}

/** How often the buses' and CANsmc masters' states are polled for alarms. */
const HEALTH_POLL_MS = 2000;
/** Bound of each poll's call: a gateway that is gone is the link's business. */
const HEALTH_CALL_MS = 1500;

/** What an alarm-worthy bus state says; "" for a healthy one. */
function busAlarm(state: BusState): string {
  switch (state) {
    case BusState.ERROR_PASSIVE:
      return "error-passive: an error counter passed 127 (wiring, termination, bit rate?)";
    case BusState.BUS_OFF:
      return "bus-off: the controller left the bus after too many transmit errors";
    case BusState.DOWN:
      return "interface down: the gateway reconnects when it comes back";
    default:
      return "";
  }
}

/** Holds `source`'s alarm to a polled condition: `text` raised while it
 * lasts (once: acknowledged, it is not raised again until it went away),
 * its other alarms cleared; "" clears them all. */
function holdAlarm(source: string, text: string): void {
  clear(source, (t) => t !== text);
  if (text && !alarms.some((a) => a.source === source && a.text === text && !a.cleared)) raise(source, text);
}

async function pollHealth(signal: AbortSignal): Promise<void> {
  const opts = { signal, timeoutMs: HEALTH_CALL_MS };
  try {
    const r = await bus.listBuses({}, opts);
    for (const b of r.buses) holdAlarm(`bus ${b.name}`, busAlarm(b.status?.state ?? BusState.UNSPECIFIED));
  } catch {
    // The link indicator tells a gateway that is gone.
  }
  try {
    const masters = await cansmc.listMasters({}, opts);
    for (const m of masters.masters) {
      const st = await cansmc.getStatus({ master: m.name }, opts);
      holdAlarm(`CANsmc ${m.name}`, st.startError ? `start failed: ${st.startError}` : "");
      for (const s of st.slaves) {
        const source = `CANsmc ${m.name} slave ${s.address}${s.name ? ` (${s.name})` : ""}`;
        let text = "";
        // A slave that backs an axis: the axis's own events say it.
        if (!s.axis) {
          if (s.state === CansmcSlaveState.LOST) text = `slave lost: ${s.consecutiveMisses} DTs missed in a row`;
          else if (s.state === CansmcSlaveState.MISSING) text = "slave missing: it did not answer at the start";
          else if (s.statusWord?.fault) text = `slave reports a fault (status word 0x${s.statusWord.raw.toString(16).padStart(4, "0")})`;
        }
        holdAlarm(source, text);
      }
    }
  } catch {
    // As above.
  }
}

/** Streams the node events, and polls the buses' and CANsmc masters'
 * states, until `signal` aborts. */
export function startAlarms(signal: AbortSignal): void {
  const poll = async () => {
    if (signal.aborted) return;
    await pollHealth(signal);
    setTimeout(() => void poll(), HEALTH_POLL_MS);
  };
  void poll();
  void keepStreaming(
    "node events",
    signal,
    (sig) => canopen.streamNodeEvents({ bus: "", nodes: [] }, { signal: sig }),
    (ev) => {
      nodeAlarm(ev);
      for (const l of nodeListeners) l(ev);
    },
  );
}

export function initAlarms(): void {
  document.getElementById("alarms-ack-all")!.addEventListener("click", () =>
    acknowledge(alarms.filter((a) => !a.acknowledged).map((a) => a.id)),
  );
  render();
}
