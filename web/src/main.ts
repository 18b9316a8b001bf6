// The dashboard's entry: tabs, token entry, stop-all, and the page's
// long-lived streams (at most two: axis state and one bus's frames).
import { setToken } from "./api";
import { initAxes, startAxes, stopAll } from "./axes";
import { initBuses, startBuses } from "./buses";

let session: AbortController | null = null;

function start(): void {
  session?.abort();
  session = new AbortController();
  void startAxes(session.signal);
  startBuses(session.signal);
}

function show(page: string): void {
  for (const p of document.querySelectorAll<HTMLElement>(".page")) {
    p.hidden = p.id !== `page-${page}`;
  }
  for (const t of document.querySelectorAll<HTMLElement>(".tab")) {
    t.classList.toggle("active", t.dataset.page === page);
  }
}

function route(): void {
  show(location.hash === "#buses" ? "buses" : "axes");
}

document.addEventListener("DOMContentLoaded", () => {
  for (const t of document.querySelectorAll<HTMLElement>(".tab")) {
    t.addEventListener("click", () => {
      location.hash = t.dataset.page ?? "axes";
    });
  }
  window.addEventListener("hashchange", route);
  route();
  document.getElementById("token-form")!.addEventListener("submit", (e) => {
    e.preventDefault();
    const input = document.getElementById("token") as HTMLInputElement;
    setToken(input.value);
    input.value = "";
    document.getElementById("notice")!.hidden = true;
    start();
  });
  document.getElementById("stop-all")!.addEventListener("click", () => void stopAll());
  initAxes();
  initBuses();
  start();
});
