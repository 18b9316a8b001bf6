// The caller's role and which of the page's buttons it may use.
//
// The page asks the gateway who it is (Session.GetCaller) whenever it
// starts or the token changes. A later PERMISSION_DENIED of the security
// layer names the role held ("... needs role engineer; wall-screen holds
// role viewer") and updates it too (a token's role changed meanwhile).
//
// NEEDS mirrors the access table (server/src/security/roles.rs) for the
// RPCs the page's buttons call.
import { Code, ConnectError } from "@connectrpc/connect";
import { type Caller, CallerRole } from "./gen/cangate/v1/session_pb";

export type Role = "viewer" | "operator" | "engineer";
const RANK: Record<Role, number> = { viewer: 0, operator: 1, engineer: 2 };

/** The least role each RPC the page calls needs (roles.rs). */
export const NEEDS = {
  AcquireControl: "operator",
  Enable: "operator",
  Disable: "operator",
  Home: "operator",
  Move: "operator",
  Jog: "operator",
  Stop: "operator",
  QuickStop: "operator",
  StopAxes: "operator",
  SetMode: "operator",
  SendNmt: "engineer",
  ReadSdo: "viewer",
  WriteSdo: "engineer",
  ScanNetwork: "viewer",
  Restart: "engineer",
  ReadParameter: "viewer",
  WriteParameter: "engineer",
} as const satisfies Record<string, Role>;
export type Rpc = keyof typeof NEEDS;

let role: Role | null = null;
let who = "";
/** The gateway lets this caller stop axes (Caller.may_stop): a viewer
 * where `[security] viewers_may_stop` is on. */
let mayStop = false;
const STOPS: readonly Rpc[] = ["Stop", "QuickStop", "StopAxes"];
interface Guarded {
  button: HTMLButtonElement;
  rpc: Rpc;
  /** Another reason to disable the button ("" for none). */
  other: () => string;
  /** The button's own tooltip, shown while it is enabled. */
  title: string;
}
const guarded: Guarded[] = [];

/** Why the role may not call `rpc`, or "" when it may (or is not known yet). */
export function refusal(rpc: Rpc): string {
  const needed = NEEDS[rpc];
  if (role === null || RANK[role] >= RANK[needed]) return "";
  if (mayStop && STOPS.includes(rpc)) return "";
  return `${rpc} needs role ${needed}; this token has role ${role}`;
}

/**
 * Puts a button under the role: disabled with the reason in its tooltip
 * when the role may not call `rpc`, else by `other` (another reason to
 * disable it, e.g. no lease held; "" for none).
 */
export function guard(button: HTMLButtonElement, rpc: Rpc, other: () => string = () => ""): void {
  const g = { button, rpc, other, title: button.title };
  guarded.push(g);
  refresh(g);
}

function refresh(g: Guarded): void {
  const why = refusal(g.rpc) || g.other();
  g.button.disabled = why !== "";
  g.button.title = why || g.title;
}

/** Re-applies the role and the other reasons to every guarded button. */
export function applyRoles(): void {
  for (let i = guarded.length - 1; i >= 0; i--) {
    const g = guarded[i];
    if (!g.button.isConnected) guarded.splice(i, 1);
    else refresh(g);
  }
  const badge = document.getElementById("role")!;
  badge.textContent = role === null ? "" : `role: ${role}${who ? ` (${who})` : ""}`;
  badge.hidden = role === null;
  if (role !== null) document.body.dataset.role = role;
  else delete document.body.dataset.role;
}

function setRole(r: Role, name: string): void {
  role = r;
  who = name;
  applyRoles();
}

/** Learns the role from a PERMISSION_DENIED of the security layer. */
export function learnFromRefusal(e: unknown): void {
  const err = ConnectError.from(e);
  if (err.code !== Code.PermissionDenied) return;
  const m = /; (.*) holds role (viewer|operator|engineer)/.exec(err.rawMessage);
  if (m) setRole(m[2] as Role, m[1]);
}

/** Asks the gateway who the caller is (`getCaller`); forgets the role
 * first. Refused (no or a wrong token) the role stays unknown: the page
 * asks for a token. */
export async function loadRole(getCaller: () => Promise<Caller>): Promise<void> {
  role = null;
  who = "";
  mayStop = false;
  applyRoles();
  try {
    const c = await getCaller();
    mayStop = c.mayStop;
    const r = ROLE_OF[c.role];
    if (r) setRole(r, c.method === "none" ? "" : c.name);
  } catch {
    // Shown by the calls that need the role; nothing to add here.
  }
}

const ROLE_OF: Partial<Record<CallerRole, Role>> = {
  [CallerRole.VIEWER]: "viewer",
  [CallerRole.OPERATOR]: "operator",
  [CallerRole.ENGINEER]: "engineer",
};
