// Axes: live state from one StreamAxisState stream, control leases
// (acquired, renewed with RenewControl, released), enable/disable, home,
// move (target, and velocity and acceleration: empty or 0 for the axis's
// maxima),
// hold-to-jog (a repeated Jog while the button is held; released, left,
// window blurred or tab hidden: Stop), stop and quick stop, and the
// always-visible stop-all and quick-stop-all (StopAxes, which needs no
// lease). A stop that fails stays on the page until acknowledged; rows
// not confirmed by a live stream are marked stale with their age.
import { AxisActivity, DriveState, Outcome, type Axis, type AxisEvent, type AxisStatus } from "./gen/cangate/v1/axes_pb";
import { Code, ConnectError } from "@connectrpc/connect";
import {
  ageText,
  axes,
  backoff,
  axesOnExit,
  clearNotice,
  el,
  errorText,
  keepStreaming,
  lostSince,
  retryAfter,
  showError,
  showStopFailed,
} from "./api";
import { clear as clearAlarm, raise as raiseAlarm } from "./alarms";
import { applyRoles, guard, type Rpc } from "./roles";
import { TimeChart } from "./chart";

interface Row {
  axis: Axis;
  /** The axis's card (data-axis, data-state, data-kind, ...). */
  tr: HTMLElement;
  cells: Record<string, HTMLElement>;
  /** The state badge. */
  badge: HTMLSpanElement;
  /** The homed icon, and the limit and home switch icons (negative, home, positive). */
  homed: HTMLSpanElement;
  switches: HTMLSpanElement;
  switchIcons: HTMLSpanElement[];
  /** The fault's one-line summary, and its full text on demand. */
  faultSummary: HTMLSpanElement;
  faultFull: HTMLDivElement;
  /** Decimals of the position readout (the axis's resolution). */
  decimals: number;
  acquire: HTMLButtonElement;
  target: HTMLInputElement;
  /** "stale N s" while the row's values are not confirmed live. */
  age: HTMLSpanElement;
  /** Since when the values are not confirmed (ms since the epoch); 0: live. */
  staleSince: number;
}

/** Stops bounded in time: a gateway that does not answer is a failed stop, shown. */
const STOP_TIMEOUT_MS = 3000;

const rows = new Map<string, Row>();
/** Leases this page holds, by axis. */
const leases = new Map<string, { lease: string; timer: number }>();
let names: string[] = [];
let jog: { axis: string; timer: number } | null = null;
/** The latest position of every axis, for the trace. */
const positions = new Map<string, number>();
let traced = "";
/** Each axis's unit, for the trace's label. */
let units = new Map<string, string>();
let trace: TimeChart | null = null;

const enumName = (e: Record<number, string>, v: number) =>
  (e[v] ?? String(v)).toLowerCase().replace(/_/g, " ");

async function run(what: string, f: () => Promise<unknown>): Promise<boolean> {
  try {
    await f();
    clearNotice();
    return true;
  } catch (e) {
    showError(what, e);
    return false;
  }
}

function options(name: string) {
  return { lease: leases.get(name)?.lease ?? "", wait: false, waitTimeoutMs: 0 };
}

/** The buttons that need a lease are enabled while the page holds one (and the role allows them). */
function setLeaseState(name: string): void {
  const row = rows.get(name);
  if (!row) return;
  row.acquire.textContent = leases.has(name) ? "Release" : "Acquire";
  showControl(row);
  applyRoles();
}

function needsLease(name: string): () => string {
  return () => (leases.has(name) ? "" : "acquire control of the axis first");
}

function dropLease(name: string): void {
  const l = leases.get(name);
  if (l) clearInterval(l.timer);
  leases.delete(name);
  setLeaseState(name);
}

async function toggleControl(name: string): Promise<void> {
  const held = leases.get(name);
  if (held) {
    dropLease(name);
    await run(`release ${name}`, () => axes.releaseControl({ lease: held.lease }));
    return;
  }
  await run(`acquire ${name}`, async () => {
    const l = await axes.acquireControl({ axes: [name], ttlMs: 3000, clientName: "dashboard" });
    const timer = window.setInterval(async () => {
      try {
        await axes.renewControl({ lease: l.lease });
      } catch (e) {
        dropLease(name);
        showError(`lease of ${name}`, e);
        raiseAlarm(`axis ${name}`, `control lease lost: ${errorText(e)}`);
      }
    }, 1000);
    leases.set(name, { lease: l.lease, timer });
    setLeaseState(name);
  });
}

/** A stop of one axis (quick: CiA 402 quick stop); a failure stays shown. */
async function stopAxis(axis: string, quick: boolean): Promise<void> {
  const what = `${quick ? "Quick stop" : "Stop"} of ${axis}`;
  try {
    const req = { axis };
    const opts = { timeoutMs: STOP_TIMEOUT_MS };
    await (quick ? axes.quickStop(req, opts) : axes.stop(req, opts));
    clearNotice();
  } catch (e) {
    showError(what, e);
    showStopFailed(what, errorText(e));
  }
}

function stopJog(): void {
  if (!jog) return;
  const { axis, timer } = jog;
  jog = null;
  clearInterval(timer);
  void stopAxis(axis, false);
}

function startJog(row: Row, sign: number): void {
  stopJog();
  const name = row.axis.name;
  const velocity = sign * row.axis.maxVelocity * 0.2;
  const send = () => axes.jog({ axis: name, velocity, acceleration: 0, options: options(name) });
  // Re-armed well within the dead-man time, so one late call does not
  // stop the axis; the gateway stops it when the calls stop.
  const period = Math.max(50, Math.floor((row.axis.jogDeadmanMs || 500) / 3));
  const timer = window.setInterval(() => {
    send().catch((e) => {
      showError(`jog ${name}`, e);
      stopJog();
    });
  }, period);
  jog = { axis: name, timer };
  void run(`jog ${name}`, send);
}

function button(label: string, cmd: string, rpc: Rpc, onClick: () => void, other?: () => string): HTMLButtonElement {
  const b = el("button", { type: "button", textContent: label });
  b.dataset.cmd = cmd;
  b.addEventListener("click", onClick);
  guard(b, rpc, other);
  return b;
}

function jogButton(row: () => Row, label: string, sign: number, lease: () => string): HTMLButtonElement {
  const b = el("button", { type: "button", textContent: label, className: "jog" });
  b.dataset.cmd = sign < 0 ? "jog-minus" : "jog-plus";
  guard(b, "Jog", lease);
  b.addEventListener("pointerdown", (e) => {
    if (b.disabled) return;
    b.setPointerCapture(e.pointerId);
    startJog(row(), sign);
  });
  for (const ev of ["pointerup", "pointercancel", "lostpointercapture"]) {
    b.addEventListener(ev, stopJog);
  }
  return b;
}

/** How an axis's state reads at a glance: the badge's colour. */
export function stateKind(s: AxisStatus): "lost" | "fault" | "moving" | "enabled" | "disabled" {
  if (s.nodeLost) return "lost";
  if (s.state === DriveState.FAULT || s.state === DriveState.FAULT_REACTION_ACTIVE || s.faultText) return "fault";
  if (s.activity !== AxisActivity.IDLE && s.activity !== AxisActivity.UNSPECIFIED) return "moving";
  if (s.state === DriveState.OPERATION_ENABLED) return "enabled";
  return "disabled";
}

/** The first sentence of a fault text, for the one-line summary. */
function faultSummary(text: string): string {
  const cut = text.search(/[:;(]\s|\.\s/);
  return cut > 0 && cut < 60 ? text.slice(0, cut) : text.length > 60 ? `${text.slice(0, 57)}…` : text;
}

function buildRow(axis: Axis): Row {
  const name = axis.name;
  const unit = axis.unit;
  const field = (cls: string, tag: "span" | "dd" = "span") => el(tag, { className: cls });
  const cells: Record<string, HTMLElement> = {
    state: field("state"),
    activity: field("activity", "dd"),
    position: field("num position"),
    velocity: field("num velocity", "dd"),
    ferr: field("num ferr", "dd"),
    control: field("control"),
    fault: field("fault"),
  };
  const input = (field: string, label: string, value: string, placeholder = "") => {
    const i = el("input", { type: "number", step: "any", value, placeholder });
    i.setAttribute("aria-label", `${name} ${label}`);
    i.dataset.field = field;
    return i;
  };
  const target = input("target", "target", "0");
  target.title = `target position in ${unit}`;
  const velocity = input("velocity", "velocity", "", `v max ${axis.maxVelocity}`);
  velocity.title = `velocity in ${unit}/s (empty: the axis's maximum, ${axis.maxVelocity} ${unit}/s)`;
  const accel = input("acceleration", "acceleration", "", `a max ${axis.maxAcceleration}`);
  accel.title = `acceleration in ${unit}/s² (empty: the axis's maximum, ${axis.maxAcceleration} ${unit}/s²)`;
  const getRow = () => rows.get(name)!;
  const opts = () => options(name);
  const lease = needsLease(name);
  const enable = button("Enable", "enable", "Enable", () => run(`enable ${name}`, () => axes.enable({ axis: name, options: opts() })), lease);
  const disable = button("Disable", "disable", "Disable", () => run(`disable ${name}`, () => axes.disable({ axis: name, options: opts() })), lease);
  const home = button("Home", "home", "Home", () => run(`home ${name}`, () => axes.home({ axis: name, options: opts() })), lease);
  const move = button(
    "Move",
    "move",
    "Move",
    () =>
      run(`move ${name}`, () =>
        axes.move({
          axis: name,
          target: Number(target.value),
          relative: false,
          velocity: Number(velocity.value) || 0,
          acceleration: Number(accel.value) || 0,
          options: opts(),
        }),
      ),
    lease,
  );
  const jogMinus = jogButton(getRow, "◀ Jog", -1, lease);
  const jogPlus = jogButton(getRow, "Jog ▶", 1, lease);
  const stop = button("Stop", "stop", "Stop", () => void stopAxis(name, false));
  const quickStop = button("Quick stop", "quick-stop", "QuickStop", () => void stopAxis(name, true));
  quickStop.title = "CiA 402 quick stop (the drive's quick stop deceleration); needs no lease";
  quickStop.classList.add("quick");
  stop.classList.add("stop");
  const acquire = button("Acquire", "acquire", "AcquireControl", () => void toggleControl(name));
  const age = el("span", { className: "stale-age" });
  age.hidden = true;
  const badge = el("span", { className: "badge" }, cells.state);
  const homed = el("span", { className: "homed", textContent: "⌂", title: "not homed" });
  // The drive's switches (0x60FD), shown only when its process data carries them.
  const switches = el(
    "span",
    { className: "switches", hidden: true },
    el("span", { className: "switch limit", textContent: "⇤", title: "negative limit switch" }),
    el("span", { className: "switch home", textContent: "●", title: "home switch" }),
    el("span", { className: "switch limit", textContent: "⇥", title: "positive limit switch" }),
  );
  switches.children[0].setAttribute("data-switch", "negative-limit");
  switches.children[1].setAttribute("data-switch", "home");
  switches.children[2].setAttribute("data-switch", "positive-limit");
  const faultFull = el("div", { className: "fault-full" });
  faultFull.hidden = true;
  const faultSummaryText = el("span", { className: "fault-summary" });
  const more = el("button", { type: "button", className: "fault-more", textContent: "details" });
  more.addEventListener("click", () => {
    faultFull.hidden = !faultFull.hidden;
    more.textContent = faultFull.hidden ? "details" : "less";
  });
  cells.fault.append(faultSummaryText, more, faultFull);
  cells.fault.hidden = true;
  const pair = (label: string, value: HTMLElement) => el("div", { className: "pair" }, el("dt", {}, label), value);
  const card = el(
    "article",
    { className: "axis" },
    el(
      "header",
      { className: "axis-head" },
      el("span", { className: "name" }, name),
      badge,
      homed,
      switches,
      el("span", { className: "control-label" }, "control: ", cells.control),
      age,
    ),
    el("div", { className: "dro" }, cells.position, el("span", { className: "dro-unit" }, unit)),
    el(
      "dl",
      { className: "minor" },
      pair(`velocity ${unit}/s`, cells.velocity),
      pair(`following error ${unit}`, cells.ferr),
      pair("activity", cells.activity),
    ),
    cells.fault,
    el(
      "div",
      { className: "cmds" },
      el("div", { className: "cmd-row" }, acquire, enable, disable, home),
      el("div", { className: "cmd-row" }, target, velocity, accel, move),
      el("div", { className: "cmd-row jogs" }, jogMinus, jogPlus, stop, quickStop),
    ),
  );
  card.dataset.axis = name;
  return {
    axis,
    tr: card,
    cells,
    badge,
    homed,
    switches,
    switchIcons: [...switches.children] as HTMLSpanElement[],
    faultSummary: faultSummaryText,
    faultFull,
    // The axis's configured decimals, else one count visible (the gateway
    // decides: Axis.display_decimals).
    decimals: axis.displayDecimals,
    acquire,
    target,
    age,
    staleSince: 0,
  };
}

/** The rows' values are no longer confirmed by a live stream. */
function markStale(): void {
  const since = lostSince() || Date.now();
  for (const row of rows.values()) {
    if (row.staleSince === 0) row.staleSince = since;
  }
  // A hidden page shows its ages when it is shown (enterAxes).
  if (shown) showAges();
}

/** The stale rows' ages (display only, every second). */
function showAges(): void {
  for (const row of rows.values()) {
    const stale = row.staleSince !== 0;
    row.tr.classList.toggle("stale", stale);
    if (stale) setData(row.tr, "stale", "true");
    else if (row.tr.dataset.stale !== undefined) delete row.tr.dataset.stale;
    setHidden(row.age, !stale);
    if (stale) setText(row.age, `stale ${ageText(row.staleSince)}`);
  }
}

/** Writes the text only when it differs: an unchanged value costs no layout. */
function setText(e: HTMLElement, text: string): void {
  if (e.textContent !== text) e.textContent = text;
}

function setData(e: HTMLElement, key: string, value: string): void {
  if (e.dataset[key] !== value) e.dataset[key] = value;
}

function setTitle(e: HTMLElement, title: string): void {
  if (e.title !== title) e.title = title;
}

function setHidden(e: HTMLElement, hidden: boolean): void {
  if (e.hidden !== hidden) e.hidden = hidden;
}

/** Who controls each axis, as its latest status or control event said. */
const holders = new Map<string, string>();

/** Who controls an axis, as the Control column shows it. */
function showControl(row: Row): void {
  const text = leases.has(row.axis.name) ? "this page" : holders.get(row.axis.name) || "—";
  setText(row.cells.control, text);
  setTitle(row.cells.control, text);
}

/** Statuses received since the cards were last drawn, the latest per axis. */
const pending = new Map<string, AxisStatus>();
let drawScheduled = false;
let lastDraw = 0;
/** The axes page is shown: its cards are drawn (a hidden page's are not). */
let shown = false;
/** Least time between two drawings of the cards: 20 a second is what an
 * eye reads of a readout, and far less than the stream brings. */
const DRAW_PERIOD_MS = 50;

/**
 * Takes an axis's status. The cards show each axis's latest status, drawn
 * at most 20 times a second and only while the axes page is shown: moving
 * axes send a status per SYNC, far more than a screen shows, and each DOM
 * write costs layout. The position trace samples the latest position.
 */
function receive(s: AxisStatus): void {
  positions.set(s.axis, s.position);
  holders.set(s.axis, s.controlledBy);
  pending.set(s.axis, s);
  scheduleDraw();
}

function scheduleDraw(): void {
  if (drawScheduled || !shown || pending.size === 0) return;
  drawScheduled = true;
  const wait = Math.max(0, lastDraw + DRAW_PERIOD_MS - performance.now());
  setTimeout(() => {
    // A hidden tab draws no frames: the timer draws there.
    if (document.hidden) drawPending();
    else requestAnimationFrame(drawPending);
  }, wait);
}

function drawPending(): void {
  drawScheduled = false;
  lastDraw = performance.now();
  if (!shown) return;
  const batch = [...pending.values()];
  pending.clear();
  for (const st of batch) update(st);
}

function update(s: AxisStatus): void {
  const row = rows.get(s.axis);
  if (!row) return;
  const state = enumName(DriveState, s.state);
  const activity = enumName(AxisActivity, s.activity);
  setText(row.cells.state, s.nodeLost ? "node lost" : state);
  setText(row.cells.activity, activity);
  setText(row.cells.position, s.position.toFixed(row.decimals));
  setText(row.cells.velocity, s.velocity.toFixed(row.decimals));
  setText(row.cells.ferr, s.followingError.toFixed(Math.min(4, row.decimals + 1)));
  showControl(row);
  setHidden(row.cells.fault, !s.faultText);
  setText(row.faultSummary, faultSummary(s.faultText));
  setTitle(row.faultSummary, s.faultText);
  setText(row.faultFull, s.faultText);
  const kind = stateKind(s);
  setData(row.badge, "kind", kind);
  setData(row.tr, "kind", kind);
  if (row.staleSince !== 0) {
    row.staleSince = 0;
    showAges();
  }
  setData(row.tr, "state", state);
  setData(row.tr, "activity", activity);
  setData(row.tr, "homed", String(s.homed));
  setTitle(row.homed, s.homed ? "homed" : "not homed");
  showSwitches(row, s);
}

/** The limit and home switch icons: shown when the drive reports its digital inputs, lit while active. */
function showSwitches(row: Row, s: AxisStatus): void {
  const di = s.digitalInputs;
  setHidden(row.switches, !di);
  if (!di) return;
  const states: [boolean, string][] = [
    [di.negativeLimitSwitch, "negative limit switch"],
    [di.homeSwitch, "home switch"],
    [di.positiveLimitSwitch, "positive limit switch"],
  ];
  states.forEach(([on, label], i) => {
    const icon = row.switchIcons[i];
    setData(icon, "active", String(on));
    setTitle(icon, `${label}: ${on ? "active" : "not active"}`);
  });
}

/** An axis's fault and its drive's node lost are alarms; the node back clears the latter. */
function axisAlarm(ev: AxisEvent): void {
  const source = `axis ${ev.axis}`;
  const at = Number(ev.timestampUs / 1000n) || Date.now();
  const k = ev.kind;
  if (k.case === "fault" && k.value.text) raiseAlarm(source, `fault: ${k.value.text}`, at);
  else if (k.case === "node") {
    if (k.value.lost) raiseAlarm(source, `drive lost: ${k.value.reason}`, at);
    else clearAlarm(source, (t) => t.startsWith("drive lost"));
  }
}

/** Stops every axis (no lease needed; quick: CiA 402 quick stop). A stop
 * that fails, or that an axis refuses, stays shown until acknowledged. */
export async function stopAll(quick = false): Promise<void> {
  const what = quick ? "QUICK STOP ALL" : "STOP ALL";
  stopJog();
  if (names.length === 0) {
    showStopFailed(what, "the page does not know the axes (the gateway was not reached)");
    return;
  }
  try {
    const r = await axes.stopAxes({ axes: names, quick, wait: false }, { timeoutMs: STOP_TIMEOUT_MS });
    const refused = r.results
      .map((x, i) => ({ axis: names[i], x }))
      .filter(({ x }) => x.outcome === Outcome.UNSPECIFIED)
      .map(({ axis, x }) => `${axis}: ${x.detail || "refused"}`);
    if (refused.length > 0) showStopFailed(what, `not stopped: ${refused.join("; ")}`);
    else clearNotice();
  } catch (e) {
    showError(what.toLowerCase(), e);
    showStopFailed(what, errorText(e));
  }
}

/** Lists the axes and streams their state until `signal` aborts. */
export async function startAxes(signal: AbortSignal): Promise<void> {
  for (const name of [...leases.keys()]) dropLease(name);
  let list: Axis[] = [];
  // Until the gateway answers (it may not be up yet), with back-off.
  for (let failures = 1; ; failures++) {
    try {
      list = (await axes.listAxes({}, { signal })).axes;
      break;
    } catch (e) {
      if (signal.aborted) return;
      showError("axes", e);
      if (ConnectError.from(e).code === Code.Unauthenticated) return;
      await retryAfter(backoff(failures), signal);
    }
  }
  rows.clear();
  names = list.map((a) => a.name);
  const select = document.getElementById("trace-axis") as HTMLSelectElement;
  select.replaceChildren(...list.map((a) => el("option", { value: a.name }, `${a.name} (${a.unit})`)));
  units = new Map(list.map((a) => [a.name, a.unit]));
  if (!names.includes(traced)) traced = names[0] ?? "";
  select.value = traced;
  trace?.setSeries([`${traced} position (${units.get(traced) ?? ""})`]);
  const tbody = document.getElementById("axes")!;
  tbody.replaceChildren();
  for (const a of list) {
    const row = buildRow(a);
    rows.set(a.name, row);
    tbody.append(row.tr);
    setLeaseState(a.name);
    if (a.status) {
      holders.set(a.name, a.status.controlledBy);
      positions.set(a.name, a.status.position);
      update(a.status);
    }
  }
  void keepStreaming(
    "axis stream",
    signal,
    (sig) => axes.streamAxisState({ axes: [], changesOnly: true }, { signal: sig }),
    (u) => {
      if (u.update.case === "status") receive(u.update.value);
      else if (u.update.case === "event") axisAlarm(u.update.value);
      if (u.update.case === "event" && u.update.value.kind.case === "control") {
        // Control changes hands without a new status (an axis at rest
        // sends none with changesOnly): the handwheel taking an axis.
        holders.set(u.update.value.axis, u.update.value.kind.value.holder);
        const row = rows.get(u.update.value.axis);
        if (row) showControl(row);
      }
    },
    markStale,
  );
}

/** The axes page is shown until `signal` aborts: its cards are drawn. */
export function enterAxes(signal: AbortSignal): void {
  shown = true;
  showAges();
  scheduleDraw();
  signal.addEventListener(
    "abort",
    () => {
      shown = false;
    },
    { once: true },
  );
}

/** Gives the page's leases back when it goes away (closed, reloaded, left)
 * instead of letting them lapse: the calls outlive the page (keepalive). */
function releaseOnExit(): void {
  for (const [name, l] of leases) {
    clearInterval(l.timer);
    void axesOnExit.releaseControl({ lease: l.lease }).catch(() => undefined);
    leases.delete(name);
  }
}

export function initAxes(): void {
  window.addEventListener("pagehide", releaseOnExit);
  trace = new TimeChart(document.getElementById("trace-chart")!, "position", 120);
  const select = document.getElementById("trace-axis") as HTMLSelectElement;
  select.addEventListener("change", () => {
    traced = select.value;
    trace?.setSeries([`${traced} position (${units.get(traced) ?? ""})`]);
  });
  setInterval(() => {
    if (shown) showAges();
  }, 1000);
  // Sampled at 20 Hz from the latest state (the stream sends changes
  // only, so an axis at rest sends nothing); drawn while shown.
  setInterval(() => {
    const p = positions.get(traced);
    if (p !== undefined) trace?.push(Date.now() / 1000, [p]);
  }, 50);
  // The dead-man side of the page: a held jog ends when the page loses
  // the user's attention.
  window.addEventListener("blur", stopJog);
  document.addEventListener("visibilitychange", () => {
    if (document.hidden) stopJog();
  });
}
