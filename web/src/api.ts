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

// Binary only: the bundle leaves protobuf's JSON codec out (build.mjs).
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

// ------------------------------------------------------------ the link

/**
 * Whether the page hears the gateway, from what its calls and streams
 * report: every message or answer says it is there (connected), every
 * error that is not an answer (the connection refused or reset, the
 * gateway shutting down, no answer in time) says it is not (lost). The
 * buses' poll (every second, each call bounded) is the heartbeat that a
 * silent stream cannot give. While lost, the streams are closed and
 * reopened with back-off, at once when the link is back.
 */
export type Link = "connecting" | "connected" | "lost" | "token";
let link: Link = "connecting";
let lostAt = 0;
const linkListeners = new Set<(l: Link) => void>();

/** Calls `f` with every change of the link; returns how to stop. */
export function onLink(f: (l: Link) => void): () => void {
  linkListeners.add(f);
  return () => linkListeners.delete(f);
}

/** When the link was lost (ms since the epoch; 0 while connected). */
export function lostSince(): number {
  return link === "connected" ? 0 : lostAt;
}

function setLink(l: Link, detail = ""): void {
  const changed = l !== link;
  if (changed) lostAt = l === "connected" ? 0 : lostAt || Date.now();
  link = l;
  const conn = document.getElementById("conn")!;
  if (detail) conn.title = detail;
  renderLink();
  if (changed) for (const f of [...linkListeners]) f(l);
}

/** Seconds since `t` (ms since the epoch), for people. */
export function ageText(t: number): string {
  const s = Math.max(0, Math.round((Date.now() - t) / 1000));
  return s < 120 ? `${s} s` : `${Math.round(s / 60)} min`;
}

function renderLink(): void {
  const conn = document.getElementById("conn")!;
  conn.textContent =
    link === "connected"
      ? "connected"
      : link === "token"
        ? "token needed"
        : link === "lost"
          ? `gateway lost ${ageText(lostAt)} ago; reconnecting`
          : "connecting…";
  conn.classList.toggle("bad", link !== "connected");
  document.body.dataset.conn = link;
}

// The ages shown while lost count up (display only: the link's state
// changes with the calls' and streams' outcomes, never on a timer).
setInterval(() => {
  if (link !== "connected") renderLink();
}, 1000);

/** An error that is not the gateway's answer: the link is gone. */
function linkError(err: ConnectError): boolean {
  return [Code.Unavailable, Code.Unknown, Code.Internal, Code.DeadlineExceeded].includes(err.code);
}

/** The connection line in the header and the notice bar. */
export function showError(what: string, e: unknown): void {
  const err = ConnectError.from(e);
  if (err.code === Code.Canceled) return;
  const notice = document.getElementById("notice")!;
  if (err.code === Code.Unauthenticated) {
    setLink("token");
    notice.textContent = `The gateway needs a token: enter it above (${err.rawMessage}).`;
  } else if (err.code === Code.PermissionDenied) {
    learnFromRefusal(err);
    notice.textContent = `${what}: not allowed for this token's role (${err.rawMessage})`;
  } else {
    if (linkError(err)) setLink("lost", `${what}: ${err.rawMessage}`);
    const abort = sdoAbort(err);
    const sdo = abort ? ` (SDO abort ${abortText(abort)})` : "";
    notice.textContent = `${what}: ${Code[err.code]}: ${err.rawMessage}${sdo}`;
  }
  notice.hidden = false;
}

/** Marks the gateway reachable and authorised (every answer does). */
export function showConnected(): void {
  if (link !== "connected") setLink("connected");
}

export function clearNotice(): void {
  document.getElementById("notice")!.hidden = true;
}

/**
 * A stop that failed, shown until the operator acknowledges it (the
 * notice bar is overwritten by the next message; this is not): the axes
 * it was for may still be moving.
 */
export function showStopFailed(what: string, why: string): void {
  const box = document.getElementById("stop-failed")!;
  const text = document.getElementById("stop-failed-text")!;
  const at = clock();
  text.textContent = `${what} FAILED at ${at}: ${why}. The axes may still be moving: use the machine's emergency stop if they are.`;
  box.dataset.count = String(Number(box.dataset.count ?? "0") + 1);
  box.hidden = false;
}

/** The text of an error, for the stop banner. */
export function errorText(e: unknown): string {
  const err = ConnectError.from(e);
  return `${Code[err.code]}: ${err.rawMessage}`;
}

export function initStopBanner(): void {
  document.getElementById("stop-failed-ack")!.addEventListener("click", () => {
    const box = document.getElementById("stop-failed")!;
    box.hidden = true;
    box.dataset.count = "0";
  });
}

/** Resolves after `ms`, or at once when the link comes back (or `signal` aborts). */
export function retryAfter(ms: number, signal: AbortSignal): Promise<void> {
  return new Promise((resolve) => {
    const done = () => {
      clearTimeout(timer);
      stop();
      signal.removeEventListener("abort", done);
      resolve();
    };
    const timer = setTimeout(done, ms);
    const stop = onLink((l) => {
      if (l === "connected") done();
    });
    signal.addEventListener("abort", done, { once: true });
  });
}

/** Back-off of the n-th retry in a row (n ≥ 1): 0.5, 1, 2, 4, 8 s. */
export function backoff(n: number): number {
  return Math.min(8000, 500 * 2 ** Math.max(0, n - 1));
}

/**
 * Runs a server stream until `signal` aborts: reopened after it fails or
 * ends, with back-off (at once when the link comes back), and closed when
 * the link is lost (a stream that says nothing cannot tell). `onEnd` runs
 * each time a stream ended. An Unauthenticated stream waits for a new
 * token instead: the caller restarts everything then.
 */
export async function keepStreaming<T>(
  what: string,
  signal: AbortSignal,
  open: (signal: AbortSignal) => AsyncIterable<T>,
  onMessage: (m: T) => void,
  onEnd: () => void = () => {},
): Promise<void> {
  let failures = 0;
  while (!signal.aborted) {
    const one = new AbortController();
    const stopOne = () => one.abort();
    signal.addEventListener("abort", stopOne, { once: true });
    const unlisten = onLink((l) => {
      if (l === "lost") one.abort();
    });
    // Counted open until it is aborted (the browser drops the connection
    // then), or it ends: a page switch closes the old page's stream
    // before it opens the next one's.
    countStream(+1);
    let counted = true;
    const uncount = () => {
      if (counted) countStream(-1);
      counted = false;
    };
    one.signal.addEventListener("abort", uncount, { once: true });
    try {
      for await (const m of open(one.signal)) {
        showConnected();
        failures = 0;
        onMessage(m);
      }
    } catch (e) {
      if (signal.aborted) return;
      if (!one.signal.aborted) {
        showError(what, e);
        if (ConnectError.from(e).code === Code.Unauthenticated) return;
      }
    } finally {
      uncount();
      unlisten();
      signal.removeEventListener("abort", stopOne);
      if (!signal.aborted) onEnd();
    }
    failures += 1;
    await retryAfter(link === "connected" ? backoff(failures) : backoff(failures + 1), signal);
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

/** A time of day as the page shows every time: 24-hour `HH:MM:SS`, local. */
export function clock(at: Date | number = new Date()): string {
  const d = typeof at === "number" ? new Date(at) : at;
  const two = (n: number) => String(n).padStart(2, "0");
  return `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
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
