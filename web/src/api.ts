// The gateway's API over gRPC-Web on the page's own origin, with the
// user's bearer token, and the page's one place for errors.
import { Code, ConnectError, createClient, type Interceptor } from "@connectrpc/connect";
import { createGrpcWebTransport } from "@connectrpc/connect-web";
import { Axes } from "./gen/cangate/v1/axes_pb";
import { Bus } from "./gen/cangate/v1/bus_pb";
import { Canopen, SdoAbortDetailsSchema, type SdoAbortDetails } from "./gen/cangate/v1/canopen_pb";
import { Cansmc } from "./gen/cangate/v1/cansmc_pb";
import { Handwheels } from "./gen/cangate/v1/handwheel_pb";
import { Session } from "./gen/cangate/v1/session_pb";
import { learnFromRefusal } from "./roles";

const TOKEN_KEY = "cangate-token";
let token = sessionStorage.getItem(TOKEN_KEY) ?? "";

/** Sets the token sent with every call (kept for this tab only). */
export function setToken(t: string): void {
  token = t.trim();
  if (token) sessionStorage.setItem(TOKEN_KEY, token);
  else sessionStorage.removeItem(TOKEN_KEY);
}

const auth: Interceptor = (next) => async (req) => {
  if (token) req.header.set("authorization", `Bearer ${token}`);
  return next(req);
};

const transport = createGrpcWebTransport({
  baseUrl: location.origin,
  useBinaryFormat: true,
  interceptors: [auth],
});

/** Axes calls that must outlive the page (the release of its leases when
 * it is closed or reloaded): fetch's keepalive lets a request finish after
 * the page is gone. */
export const axesOnExit = createClient(
  Axes,
  createGrpcWebTransport({
    baseUrl: location.origin,
    useBinaryFormat: true,
    interceptors: [auth],
    fetch: (input, init) => globalThis.fetch(input, { ...init, keepalive: true }),
  }),
);

export const bus = createClient(Bus, transport);
export const axes = createClient(Axes, transport);
export const canopen = createClient(Canopen, transport);
export const handwheels = createClient(Handwheels, transport);
export const cansmc = createClient(Cansmc, transport);
export const session = createClient(Session, transport);

/**
 * The SDO abort of an error, from the SdoAbortDetails the gateway puts in
 * the grpc-status-details-bin trailer (canopen.proto, "The error model").
 */
export function sdoAbort(e: unknown): SdoAbortDetails | undefined {
  return ConnectError.from(e).findDetails(SdoAbortDetailsSchema)[0];
}

/** An SDO abort as people read it: `0x06010002 attempt to write a read only object`. */
export function abortText(a: SdoAbortDetails): string {
  return `0x${a.code.toString(16).toUpperCase().padStart(8, "0")} ${a.name}`;
}

/** The connection line in the header and the notice bar. */
export function showError(what: string, e: unknown): void {
  const err = ConnectError.from(e);
  if (err.code === Code.Canceled) return;
  const conn = document.getElementById("conn")!;
  const notice = document.getElementById("notice")!;
  if (err.code === Code.Unauthenticated) {
    conn.textContent = "token needed";
    conn.classList.add("bad");
    notice.textContent = `The gateway needs a token: enter it above (${err.rawMessage}).`;
  } else if (err.code === Code.PermissionDenied) {
    learnFromRefusal(err);
    notice.textContent = `${what}: not allowed for this token's role (${err.rawMessage})`;
  } else {
    const abort = sdoAbort(err);
    const sdo = abort ? ` (SDO abort ${abortText(abort)})` : "";
    notice.textContent = `${what}: ${Code[err.code]}: ${err.rawMessage}${sdo}`;
  }
  notice.hidden = false;
}

/** Marks the gateway reachable and authorised. */
export function showConnected(): void {
  const conn = document.getElementById("conn")!;
  conn.textContent = "connected";
  conn.classList.remove("bad");
}

export function clearNotice(): void {
  document.getElementById("notice")!.hidden = true;
}

/**
 * Runs a server stream until `signal` aborts, reopening it a second after
 * it fails (an Unauthenticated stream waits for a new token instead: the
 * caller restarts everything then).
 */
export async function keepStreaming<T>(
  what: string,
  signal: AbortSignal,
  open: (signal: AbortSignal) => AsyncIterable<T>,
  onMessage: (m: T) => void,
): Promise<void> {
  while (!signal.aborted) {
    countStream(+1);
    try {
      for await (const m of open(signal)) {
        showConnected();
        onMessage(m);
      }
    } catch (e) {
      if (signal.aborted) return;
      showError(what, e);
      if (ConnectError.from(e).code === Code.Unauthenticated) return;
    } finally {
      countStream(-1);
    }
    await new Promise((r) => setTimeout(r, 1000));
  }
}

let openStreams = 0;
let mostStreams = 0;

/**
 * Counts the page's open server streams (on <body data-streams> and, the
 * most at once, data-streams-max): the page keeps at most three, well
 * within the 6 connections per origin of HTTP/1.1 (the browser test
 * checks it).
 */
function countStream(delta: number): void {
  openStreams += delta;
  mostStreams = Math.max(mostStreams, openStreams);
  document.body.dataset.streams = String(openStreams);
  document.body.dataset.streamsMax = String(mostStreams);
}

export function el<K extends keyof HTMLElementTagNameMap>(
  tag: K,
  props: Partial<HTMLElementTagNameMap[K]> = {},
  ...children: (Node | string)[]
): HTMLElementTagNameMap[K] {
  const e = Object.assign(document.createElement(tag), props);
  e.append(...children);
  return e;
}
