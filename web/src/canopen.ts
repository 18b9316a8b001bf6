// CANopen: the nodes of every CANopen bus (NMT state, heartbeat age,
// identity, active error, EMCY history; polled with ListNodes while the
// page is shown), their events as they happen (one StreamNodeEvents
// stream while the page is shown), NMT buttons per node, and an SDO panel
// (read/write by index:subindex or by the object's name from the node's
// EDS, with a typed value; an abort is shown with its code and CiA 301 name
// from the SdoAbortDetails of the error).
//
// A "Scan network" button runs ScanNetwork on a CANopen bus (those of the
// listed nodes) and lists the nodes that answered (<li data-node>).
//
// The object picker is fed by ListObjects for the chosen node (once per
// node while the page lives): "Find" filters it by name or address, and
// choosing an object fills index and sub-index, preselects its EDS type and
// shows its access, PDO mappability, default and limits; reads and writes
// then name it (ReadSdoRequest.object), so the gateway resolves it with the
// EDS. Typing an index or sub-index goes back to addressing by number. With
// "EDS type" and an address, a write learns the type from a read of the
// object first (the value's type in ReadSdoResponse).
import { Code, ConnectError } from "@connectrpc/connect";
import { create } from "@bufbuild/protobuf";
import {
  DataType,
  NmtCommand,
  NmtState,
  ValueSchema,
  type Node,
  ObjectAccess,
  type ObjectInfo,
  type Value,
} from "./gen/cangate/v1/canopen_pb";
import { abortText, canopen, clearNotice, clock, el, sdoAbort, showConnected, showError } from "./api";
import { onNodeEvent } from "./alarms";
import { emcyText, enumName, eventText, hex } from "./events";
import { applyRoles, guard } from "./roles";


/** NMT buttons: label, command. */
const NMT: [string, NmtCommand][] = [
  ["Start", NmtCommand.START],
  ["Stop", NmtCommand.STOP],
  ["Pre-op", NmtCommand.ENTER_PRE_OPERATIONAL],
  ["Reset", NmtCommand.RESET_NODE],
];

const MAX_EVENTS = 200;
let events: string[] = [];
/** EDS types learnt from reads, by "bus/node/index/sub". */
const edsTypes = new Map<string, DataType>();
/** Each node's dictionary (ListObjects), by "bus/node"; a string says why there is none. */
const dictionaries = new Map<string, ObjectInfo[] | string>();
/** Options shown in the picker at most. */
const MAX_PICKS = 200;

function time(ns: bigint): string {
  return clock(Number(ns / 1_000_000n));
}

function nodeKey(n: { bus: string; id: number }): string {
  return `${n.bus}/${n.id}`;
}

function renderNodes(list: Node[]): void {
  const tbody = document.querySelector("#nodes tbody")!;
  // Rows are rebuilt only when the set of nodes changes, so that a
  // button under the pointer stays the same element.
  const keys = list.map(nodeKey).join(",");
  if (tbody.getAttribute("data-keys") !== keys) {
    tbody.setAttribute("data-keys", keys);
    tbody.replaceChildren(...list.map(buildRow));
    const select = document.getElementById("sdo-node") as HTMLSelectElement;
    const before = select.value;
    select.replaceChildren(
      ...list.map((n) => el("option", { value: nodeKey(n) }, `${n.bus} node ${n.id}${n.name ? ` (${n.name})` : ""}`)),
    );
    if (before && list.some((n) => nodeKey(n) === before)) select.value = before;
    if (select.value !== before) void loadObjects();
    const scanBus = document.getElementById("scan-bus") as HTMLSelectElement;
    const buses = [...new Set(list.map((n) => n.bus))];
    const was = scanBus.value;
    scanBus.replaceChildren(...buses.map((b) => el("option", { value: b }, b)));
    if (buses.includes(was)) scanBus.value = was;
  }
  for (const n of list) updateRow(n);
  const hist = list.flatMap((n) => n.emcyHistory.map((e) => ({ n, e })));
  hist.sort((a, b) => (a.e.timestampNs < b.e.timestampNs ? 1 : -1));
  document.getElementById("emcy-history")!.replaceChildren(
    ...(hist.length === 0
      ? [el("li", { className: "meta" }, "no EMCY received")]
      : hist.map(({ n, e }) => el("li", {}, `${time(e.timestampNs)}  ${n.bus} node ${n.id}: ${emcyText(e)}`))),
  );
}

function buildRow(n: Node): HTMLTableRowElement {
  const cmds = el("td", { className: "cmds" });
  for (const [label, command] of NMT) {
    const b = el("button", { type: "button", textContent: label });
    b.dataset.cmd = `nmt-${NmtCommand[command].toLowerCase()}`;
    b.addEventListener("click", () => void nmt(n.bus, n.id, command, label));
    guard(b, "SendNmt");
    cmds.append(b);
  }
  const cell = (cls: string) => el("td", { className: cls });
  const tr = el(
    "tr",
    {},
    el("td", {}, n.bus),
    el("td", { className: "num" }, String(n.id)),
    el("td", {}, n.name || n.deviceName),
    cell("nmt"),
    cell("num hb"),
    cell("device"),
    cell("identity"),
    cell("fault"),
    cell("num emcys"),
    cmds,
  );
  tr.dataset.bus = n.bus;
  tr.dataset.node = String(n.id);
  return tr;
}

function updateRow(n: Node): void {
  const tr = document.querySelector<HTMLTableRowElement>(`#nodes tr[data-bus="${n.bus}"][data-node="${n.id}"]`);
  if (!tr) return;
  const set = (cls: string, text: string) => {
    tr.querySelector(`td.${cls.split(" ").join(".")}`)!.textContent = text;
  };
  const state = enumName(NmtState, n.state);
  set("nmt", state);
  tr.dataset.nmt = state;
  set(
    "num hb",
    n.heartbeatAgeMs === undefined ? "—" : `${n.heartbeatAgeMs} ms${n.heartbeatLost ? " (lost)" : ""}`,
  );
  tr.classList.toggle("lost", n.heartbeatLost);
  set("device", n.deviceName + (n.deviceType === undefined ? "" : ` (type ${hex(n.deviceType, 8)})`));
  const id = n.identity;
  set(
    "identity",
    id ? `vendor ${hex(id.vendorId, 8)} product ${hex(id.productCode, 8)} rev ${hex(id.revision, 8)} serial ${id.serial}` : "—",
  );
  set("fault", n.activeError ? emcyText(n.activeError) : "");
  set("num emcys", String(n.emcyHistory.length));
}

async function nmt(bus: string, node: number, command: NmtCommand, label: string): Promise<void> {
  try {
    await canopen.sendNmt({ bus, node, command });
    clearNotice();
    logEvent(`${clock()}  ${bus} node ${node}: NMT ${label} sent`);
  } catch (e) {
    showError(`NMT ${label} to ${bus} node ${node}`, e);
  }
}

function logEvent(line: string): void {
  events.push(line);
  if (events.length > MAX_EVENTS) events = events.slice(-MAX_EVENTS);
  const pre = document.getElementById("node-events")!;
  pre.textContent = events.join("\n");
  pre.scrollTop = pre.scrollHeight;
}

// ---- SDO panel ----

type Target = { bus: string; node: number; index: number; subindex: number; object: string };

/** The object chosen in the picker ("" when addressing by number). */
function pickedName(): string {
  return (document.getElementById("sdo-object") as HTMLSelectElement).value;
}

/** What a request targets: the picked object by name, else index:subindex. */
function sdoTarget(): Target | string {
  const key = (document.getElementById("sdo-node") as HTMLSelectElement).value;
  const slash = key.lastIndexOf("/");
  if (slash < 0) return "no node selected";
  const object = pickedName();
  if (object) return { bus: key.slice(0, slash), node: Number(key.slice(slash + 1)), index: 0, subindex: 0, object };
  const index = Number.parseInt((document.getElementById("sdo-index") as HTMLInputElement).value.replace(/^0x/i, ""), 16);
  const subText = (document.getElementById("sdo-sub") as HTMLInputElement).value.trim();
  const subindex = /^0x/i.test(subText) ? Number.parseInt(subText.slice(2), 16) : Number.parseInt(subText || "0", 10);
  if (!(index >= 0 && index <= 0xffff)) return "index: 1 to 4 hex digits, e.g. 1008";
  if (!(subindex >= 0 && subindex <= 0xff)) return "sub-index: 0 to 255 (or 0x..)";
  return { bus: key.slice(0, slash), node: Number(key.slice(slash + 1)), index, subindex, object: "" };
}

function objectKey(t: Target): string {
  return t.object ? `${t.bus}/${t.node}/${t.object}` : `${t.bus}/${t.node}/${t.index}/${t.subindex}`;
}

/** "0x1008:00" */
function address(o: { index: number; subindex: number }): string {
  return `${hex(o.index, 4)}:${o.subindex.toString(16).toUpperCase().padStart(2, "0")}`;
}

/** What a request is about, for its result line. */
function targetText(t: Target): string {
  return `${t.bus} node ${t.node} ${t.object ? JSON.stringify(t.object) : `${hex(t.index, 4)}:${t.subindex}`}`;
}

// ---- Object picker (ListObjects) ----

function chosenNodeKey(): string {
  return (document.getElementById("sdo-node") as HTMLSelectElement).value;
}

/** Loads the chosen node's dictionary once, then fills the picker. */
async function loadObjects(): Promise<void> {
  const key = chosenNodeKey();
  const slash = key.lastIndexOf("/");
  if (slash < 0) return;
  if (!dictionaries.has(key)) {
    try {
      const r = await canopen.listObjects({ bus: key.slice(0, slash), node: Number(key.slice(slash + 1)) });
      dictionaries.set(key, r.objects);
    } catch (e) {
      const err = ConnectError.from(e);
      // Not kept when it may pass later (a role, the connection).
      const why = err.code === Code.FailedPrecondition ? "no EDS: address objects by index" : `no object list: ${err.rawMessage}`;
      if (err.code === Code.FailedPrecondition) dictionaries.set(key, why);
      if (key === chosenNodeKey()) fillPicker(why);
      return;
    }
  }
  if (key === chosenNodeKey()) fillPicker();
}

/** The picker's options: the chosen node's objects matching "Find". */
function fillPicker(why?: string): void {
  const select = document.getElementById("sdo-object") as HTMLSelectElement;
  const dict = dictionaries.get(chosenNodeKey());
  const before = select.value;
  const query = (document.getElementById("sdo-search") as HTMLInputElement).value.trim().toLowerCase();
  const bare = query.replace(/^0x/, "");
  const all = Array.isArray(dict) ? dict : [];
  const matches = all.filter(
    (o) =>
      query === "" ||
      o.name.toLowerCase().includes(query) ||
      address(o).toLowerCase().replace("0x", "").startsWith(bare),
  );
  const note = why ?? (typeof dict === "string" ? dict : `${matches.length} of ${all.length} objects`);
  select.replaceChildren(
    el("option", { value: "" }, `by index/sub-index (${note})`),
    ...matches.slice(0, MAX_PICKS).map((o) => {
      const opt = el("option", { value: o.name }, `${address(o)} ${o.name} — ${typeLabel(o)}, ${accessName(o.access)}`);
      opt.dataset.index = String(o.index);
      opt.dataset.sub = String(o.subindex);
      return opt;
    }),
  );
  // Keep the choice while it still matches; a search with one match picks it.
  if (before && matches.some((o) => o.name === before)) select.value = before;
  else if (query !== "" && matches.length === 1) select.value = matches[0].name;
  else select.value = "";
  if (select.value !== before) picked();
}

function typeLabel(o: ObjectInfo): string {
  return o.type === DataType.UNSPECIFIED ? `type ${hex(o.typeCode, 4)}` : typeName(o.type);
}

function accessName(a: ObjectAccess): string {
  return (ObjectAccess[a] ?? String(a)).toLowerCase();
}

/** An object was picked (or unpicked): fill address, type and its facts. */
function picked(): void {
  const name = pickedName();
  const info = document.getElementById("sdo-object-info")!;
  const dict = dictionaries.get(chosenNodeKey());
  const o = name && Array.isArray(dict) ? dict.find((x) => x.name === name) : undefined;
  if (!o) {
    // Back to an address typed by hand: the gateway takes the type from
    // the EDS again, not the one of the object picked before.
    info.textContent = "";
    delete info.dataset.object;
    (document.getElementById("sdo-type") as HTMLSelectElement).value = "0";
    edsOption(undefined);
    return;
  }
  (document.getElementById("sdo-index") as HTMLInputElement).value = o.index.toString(16).toUpperCase().padStart(4, "0");
  (document.getElementById("sdo-sub") as HTMLInputElement).value = String(o.subindex);
  (document.getElementById("sdo-type") as HTMLSelectElement).value = String(o.type);
  edsOption(o.type === DataType.UNSPECIFIED ? undefined : o.type);
  const limits = o.lowLimit || o.highLimit ? `, limits ${o.lowLimit ? formatValue(o.lowLimit) : "…"} to ${o.highLimit ? formatValue(o.highLimit) : "…"}` : "";
  const dflt = o.defaultValue ? formatValue(o.defaultValue) : o.defaultText;
  info.textContent =
    `${address(o)} ${o.name}: ${typeLabel(o)}, ${accessName(o.access)}` +
    `${o.pdoMappable ? ", PDO-mappable" : ""}${dflt ? `, default ${dflt}` : ""}${limits}`;
  info.dataset.object = o.name;
}

function chosenType(): DataType {
  return Number((document.getElementById("sdo-type") as HTMLSelectElement).value) as DataType;
}

function typeName(t: DataType): string {
  return DataType[t] ?? String(t);
}

/** A read value for people; integers in decimal and hex. */
export function formatValue(v: Value): string {
  const x = v.value;
  switch (x.case) {
    case "boolValue":
      return String(x.value);
    case "intValue":
      return String(x.value);
    case "uintValue":
      return `${x.value} (0x${x.value.toString(16).toUpperCase()})`;
    case "realValue":
      return String(x.value);
    case "stringValue":
      return JSON.stringify(x.value);
    case "bytesValue":
      return bytesHex(x.value);
    default:
      return "(no value)";
  }
}

function bytesHex(b: Uint8Array): string {
  return Array.from(b, (x) => x.toString(16).toUpperCase().padStart(2, "0")).join(" ");
}

/** The typed value of the value field for `type`, or why it is not one. */
export function parseValue(type: DataType, text: string): Value | string {
  const t = text.trim();
  const v = (value: Value["value"]) => create(ValueSchema, { type, value });
  const int = () => {
    try {
      return BigInt(t);
    } catch {
      return null;
    }
  };
  switch (type) {
    case DataType.BOOLEAN:
      if (/^(true|1)$/i.test(t)) return v({ case: "boolValue", value: true });
      if (/^(false|0)$/i.test(t)) return v({ case: "boolValue", value: false });
      return "BOOLEAN: true or false";
    case DataType.INTEGER8:
    case DataType.INTEGER16:
    case DataType.INTEGER32:
    case DataType.INTEGER64: {
      const n = int();
      return n === null ? `${typeName(type)}: an integer (or 0x..)` : v({ case: "intValue", value: n });
    }
    case DataType.UNSIGNED8:
    case DataType.UNSIGNED16:
    case DataType.UNSIGNED32:
    case DataType.UNSIGNED64: {
      const n = int();
      return n === null || n < 0n ? `${typeName(type)}: a non-negative integer (or 0x..)` : v({ case: "uintValue", value: n });
    }
    case DataType.REAL32:
    case DataType.REAL64: {
      const n = Number(t);
      return t === "" || Number.isNaN(n) ? `${typeName(type)}: a number` : v({ case: "realValue", value: n });
    }
    case DataType.VISIBLE_STRING:
    case DataType.UNICODE_STRING:
      return v({ case: "stringValue", value: text });
    case DataType.OCTET_STRING:
    case DataType.DOMAIN: {
      const digits = t.replace(/\s+/g, "");
      if (!/^([0-9a-fA-F]{2})*$/.test(digits)) return `${typeName(type)}: hex bytes, e.g. DE AD BE EF`;
      const bytes = new Uint8Array(digits.length / 2);
      for (let i = 0; i < bytes.length; i++) bytes[i] = Number.parseInt(digits.slice(2 * i, 2 * i + 2), 16);
      return v({ case: "bytesValue", value: bytes });
    }
    default:
      return "choose a type";
  }
}

function showSdo(ok: boolean, text: string, abort?: string): void {
  const out = document.getElementById("sdo-result")!;
  out.textContent = text;
  out.className = ok ? "sdo-ok" : "sdo-error";
  out.dataset.outcome = ok ? "ok" : "error";
  const ab = document.getElementById("sdo-abort")!;
  ab.textContent = abort ?? "";
  ab.hidden = !abort;
}

function showSdoError(what: string, e: unknown): void {
  const err = ConnectError.from(e);
  if (err.code === Code.PermissionDenied || err.code === Code.Unauthenticated) showError(what, e);
  const a = sdoAbort(err);
  showSdo(false, `${what}: ${Code[err.code]}: ${err.rawMessage}`, a ? `SDO abort ${abortText(a)}${a.fromNode ? "" : " (sent by the gateway)"}` : undefined);
}

async function readSdo(): Promise<void> {
  const t = sdoTarget();
  if (typeof t === "string") return showSdo(false, t);
  const what = `read ${targetText(t)}`;
  try {
    const r = await canopen.readSdo({ ...t, type: chosenType() });
    if (r.value && chosenType() === DataType.UNSPECIFIED) {
      edsTypes.set(objectKey(t), r.value.type);
      edsOption(r.value.type);
    }
    const typed = r.value ? `${typeName(r.value.type)} ${formatValue(r.value)}` : "(type unknown)";
    showSdo(true, `${what}: ${typed}; raw [${r.raw.length}] ${bytesHex(r.raw)}`);
    const input = document.getElementById("sdo-value") as HTMLInputElement;
    if (r.value?.value.case === "stringValue") input.value = r.value.value.value;
    else if (r.value?.value.case === "bytesValue") input.value = bytesHex(r.value.value.value);
    else if (r.value?.value.case !== undefined && r.value) input.value = String(r.value.value.value);
  } catch (e) {
    showSdoError(what, e);
  }
}

/** The default type option names the EDS type once a read told it. */
function edsOption(t: DataType | undefined): void {
  const opt = document.querySelector<HTMLOptionElement>(`#sdo-type option[value="0"]`)!;
  opt.textContent = t === undefined ? "EDS type" : `EDS type (${typeName(t)})`;
}

async function writeSdo(): Promise<void> {
  const t = sdoTarget();
  if (typeof t === "string") return showSdo(false, t);
  const what = `write ${targetText(t)}`;
  try {
    let type = chosenType();
    if (type === DataType.UNSPECIFIED) {
      type = edsTypes.get(objectKey(t)) ?? DataType.UNSPECIFIED;
      if (type === DataType.UNSPECIFIED) {
        // The EDS type, from a read (a write-only object cannot be read:
        // then the type must be chosen).
        const r = await canopen.readSdo({ ...t, type: DataType.UNSPECIFIED });
        if (!r.value) return showSdo(false, `${what}: the EDS does not type this object: choose a type`);
        type = r.value.type;
        edsTypes.set(objectKey(t), type);
        edsOption(type);
      }
    }
    const value = parseValue(type, (document.getElementById("sdo-value") as HTMLInputElement).value);
    if (typeof value === "string") return showSdo(false, `${what}: ${value}`);
    const r = await canopen.writeSdo({ ...t, data: { case: "value", value } });
    showSdo(true, `${what}: ${typeName(type)} ${formatValue(value)} written (${r.bytes} bytes)`);
  } catch (e) {
    showSdoError(what, e);
  }
}

// ---- Scan ----

async function scan(button: HTMLButtonElement): Promise<void> {
  const bus = (document.getElementById("scan-bus") as HTMLSelectElement).value;
  const status = document.getElementById("scan-status")!;
  const out = document.getElementById("scan-result")!;
  if (!bus) {
    status.textContent = "no CANopen bus listed yet";
    return;
  }
  button.disabled = true;
  status.textContent = `scanning ${bus}…`;
  delete out.dataset.bus;
  const t0 = performance.now();
  try {
    const r = await canopen.scanNetwork({ bus, timeoutMs: 0 });
    clearNotice();
    const ms = Math.round(performance.now() - t0);
    status.textContent = `${bus}: ${r.nodes.length} node${r.nodes.length === 1 ? "" : "s"} answered (${ms} ms)`;
    out.replaceChildren(
      ...r.nodes.map((n) => {
        const id = n.identity;
        const li = el(
          "li",
          {},
          `node ${n.id}${n.name ? ` (${n.name})` : ""}: ${n.deviceName || "no device name"}` +
            (n.deviceType === undefined ? "" : `, type ${hex(n.deviceType, 8)}`) +
            (id ? `, vendor ${hex(id.vendorId, 8)} product ${hex(id.productCode, 8)}` : "") +
            (n.configured ? "" : " (not configured)"),
        );
        li.dataset.node = String(n.id);
        return li;
      }),
    );
    out.dataset.bus = bus;
  } catch (e) {
    status.textContent = "";
    showError(`Scan of ${bus}`, e);
  } finally {
    button.disabled = false;
    // The role may still forbid it (re-applied by the guard's refresh).
    applyRoles();
  }
}

export function initCanopen(): void {
  const scanButton = document.getElementById("scan") as HTMLButtonElement;
  scanButton.addEventListener("click", () => void scan(scanButton));
  guard(scanButton, "ScanNetwork");
  const select = document.getElementById("sdo-type") as HTMLSelectElement;
  const types = Object.values(DataType).filter((v): v is DataType => typeof v === "number" && v !== DataType.UNSPECIFIED);
  select.replaceChildren(
    el("option", { value: "0" }, "EDS type"),
    ...types.map((t) => el("option", { value: String(t) }, typeName(t))),
  );
  const forget = () => edsOption(undefined);
  for (const id of ["sdo-node", "sdo-index", "sdo-sub"]) document.getElementById(id)!.addEventListener("change", forget);
  // Typing an address goes back to addressing by number.
  const unpick = () => {
    const obj = document.getElementById("sdo-object") as HTMLSelectElement;
    if (obj.value) {
      obj.value = "";
      picked();
    }
  };
  for (const id of ["sdo-index", "sdo-sub"]) document.getElementById(id)!.addEventListener("input", unpick);
  document.getElementById("sdo-node")!.addEventListener("change", () => void loadObjects());
  document.getElementById("sdo-search")!.addEventListener("input", () => fillPicker());
  document.getElementById("sdo-object")!.addEventListener("change", picked);
  const read = document.getElementById("sdo-read") as HTMLButtonElement;
  const write = document.getElementById("sdo-write") as HTMLButtonElement;
  read.addEventListener("click", () => void readSdo());
  write.addEventListener("click", () => void writeSdo());
  guard(read, "ReadSdo");
  guard(write, "WriteSdo");
  document.getElementById("sdo-form")!.addEventListener("submit", (e) => {
    e.preventDefault();
    void readSdo();
  });
}

/** Polls the nodes and streams their events while the page is shown. */
export function enterCanopen(signal: AbortSignal): void {
  const poll = async () => {
    if (signal.aborted) return;
    try {
      const r = await canopen.listNodes({ bus: "" }, { signal });
      showConnected();
      renderNodes(r.nodes);
    } catch (e) {
      if (signal.aborted) return;
      showError("CANopen nodes", e);
    }
    setTimeout(poll, 1000);
  };
  void poll();
  // The page's share of the alarms' node-event stream (one stream for both).
  const stop = onNodeEvent((ev) => logEvent(`${time(ev.timestampNs)}  ${ev.bus} node ${ev.node}: ${eventText(ev)}`));
  signal.addEventListener("abort", stop, { once: true });
}
