// How the page words CANopen node events and EMCYs, for the CANopen
// page's log and the alarm list alike.
import { NmtState, type Emcy, type NodeEvent } from "./gen/cangate/v1/canopen_pb";

export const enumName = (e: Record<number, string>, v: number) =>
  (e[v] ?? String(v)).toLowerCase().replace(/_/g, " ");

export const hex = (n: number | bigint, width: number) => `0x${n.toString(16).toUpperCase().padStart(width, "0")}`;

/** `0x8130 life guard or heartbeat error, register 0x11 [generic, communication]`. */
export function emcyText(e: Emcy): string {
  const bits = e.registerBits.length > 0 ? ` [${e.registerBits.join(", ")}]` : "";
  return `${hex(e.code, 4)} ${e.codeName}, register ${hex(e.register, 2)}${bits}`;
}

export function eventText(ev: NodeEvent): string {
  const e = ev.event;
  switch (e.case) {
    case "bootUp":
      return "boot-up";
    case "stateChanged":
      return `NMT ${enumName(NmtState, e.value.from)} → ${enumName(NmtState, e.value.to)}`;
    case "heartbeatLost":
      return `heartbeat lost (timeout ${e.value.timeoutMs} ms)`;
    case "heartbeatRecovered":
      return `heartbeat back after ${e.value.silentMs} ms (${enumName(NmtState, e.value.state)})`;
    case "emcy":
      return `EMCY ${emcyText(e.value)}`;
    case "lost":
      return `${e.value.count} events missed (read too slowly)`;
    case "bootCompleted":
      return "boot procedure completed";
    case "bootFailed":
      return `boot procedure failed: ${e.value.reason}`;
    case "guardingToggleError":
      return `node guarding toggle error (${e.value.count} so far)`;
    default:
      return "unknown event";
  }
}
