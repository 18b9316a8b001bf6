// The dashboard's entry: tabs, token entry, the role, stop-all, and the
// page's long-lived streams: the axes' state (always: the axes page and
// stop-all need it), the nodes' events (always: the alarms need them) and
// at most one more for the page shown (a bus's frames, a handwheel's
// feed, ...), opened when its tab is shown and closed when it is left.
// Three at most (data-streams-max on <body>).
import { clearNotice, initStopBanner, session as sessionApi, setToken } from "./api";
import { initAlarms, startAlarms } from "./alarms";
import { enterAxes, initAxes, startAxes, stopAll } from "./axes";
import { enterBuses, initBuses, startBuses } from "./buses";
import { enterCanopen, initCanopen } from "./canopen";
import { enterCansmc, initCansmc } from "./cansmc";
import { enterHandwheels } from "./handwheel";
import { guard, loadRole } from "./roles";

const PAGES: Record<string, ((signal: AbortSignal) => void) | null> = {
  buses: enterBuses,
  axes: enterAxes,
  canopen: enterCanopen,
  handwheel: enterHandwheels,
  cansmc: enterCansmc,
  alarms: null,
};

let session: AbortController | null = null;
let pageCtl: AbortController | null = null;
let current = "";

function start(): void {
  session?.abort();
  session = new AbortController();
  const signal = session.signal;
  void loadRole(() => sessionApi.getCaller({}, { signal }));
  void startAxes(signal);
  startAlarms(signal);
  startBuses(signal);
  enter(current);
}

/** Opens the shown page's own polling and stream, closing the last one's. */
function enter(page: string): void {
  pageCtl?.abort();
  pageCtl = new AbortController();
  const ctl = pageCtl;
  session?.signal.addEventListener("abort", () => ctl.abort(), { once: true });
  PAGES[page]?.(ctl.signal);
}

function show(page: string): void {
  for (const p of document.querySelectorAll<HTMLElement>(".page")) {
    p.hidden = p.id !== `page-${page}`;
  }
  for (const t of document.querySelectorAll<HTMLElement>(".tab")) {
    t.classList.toggle("active", t.dataset.page === page);
  }
  if (page !== current) {
    // A message about the page left does not follow the operator to the
    // next one (a failed stop keeps its own banner until acknowledged).
    if (current) clearNotice();
    current = page;
    enter(page);
  }
}

function route(): void {
  const page = location.hash.slice(1);
  show(page in PAGES ? page : "axes");
}

document.addEventListener("DOMContentLoaded", () => {
  for (const t of document.querySelectorAll<HTMLElement>(".tab")) {
    t.addEventListener("click", () => {
      location.hash = t.dataset.page ?? "axes";
    });
  }
  window.addEventListener("hashchange", route);
  document.getElementById("token-form")!.addEventListener("submit", (e) => {
    e.preventDefault();
    const input = document.getElementById("token") as HTMLInputElement;
    setToken(input.value);
    input.value = "";
    document.getElementById("notice")!.hidden = true;
    start();
  });
  const stopAllButton = document.getElementById("stop-all") as HTMLButtonElement;
  stopAllButton.addEventListener("click", () => void stopAll());
  guard(stopAllButton, "StopAxes");
  const quickStopAllButton = document.getElementById("quick-stop-all") as HTMLButtonElement;
  quickStopAllButton.addEventListener("click", () => void stopAll(true));
  guard(quickStopAllButton, "StopAxes");
  initStopBanner();
  initAlarms();
  initAxes();
  initBuses();
  initCanopen();
  initCansmc();
  route();
  start();
});
