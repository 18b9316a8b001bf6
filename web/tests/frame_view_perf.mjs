// Measures the dashboard's live frame view under load, in the system's
// headless Chromium (puppeteer-core); started by the bench binary
// `dashboard_bench`, which owns the gateway, loads its bus, and reads the
// browser's CPU time from /proc.
//
//   node web/tests/frame_view_perf.mjs URL MARKER_ID_HEX [profile]
//
// With "profile", the page's main thread is profiled (Chrome DevTools
// protocol) from "profile-start" on stdin to the report, whose JSON then
// has "profile_top": the functions with the most self time, in ms.
//
// Opens URL#buses (the live view of the first bus) and watches the view's
// text: each line of the marker identifier carries, in its 8 data bytes
// (little-endian), the time the bench put it on the bus, in µs since the
// epoch; the delay is the time the line is first on the screen (the view's
// text replaced, after the page's rendering) minus that. Protocol on
// stdout/stdin, a line each: "ready" once the view streams; then on stdin
// "report" -> one JSON line {"delays_us": [...], "rate_text": "...",
// "lost_text": "..."}; "show PAGE" -> the dashboard's page PAGE (axes,
// canopen, ...) is shown, then "shown PAGE"; on "quit" it exits.
import puppeteer from "puppeteer-core";
import { createInterface } from "node:readline";

const [url, markerHex, profiling] = process.argv.slice(2);
const chromium = process.env.CANGATE_CHROMIUM || "/usr/bin/chromium";
const rl = createInterface({ input: process.stdin });
const say = (line) => process.stdout.write(line + "\n");

const browser = await puppeteer.launch({
  executablePath: chromium,
  headless: true,
  args: ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"],
});
try {
  const page = await browser.newPage();
  await page.setViewport({ width: 1400, height: 800 });
  await page.goto(`${url}#buses`, { waitUntil: "load" });
  await page.waitForFunction(
    () => (document.getElementById("frames")?.textContent ?? "").length > 0,
    { timeout: 30_000 },
  );
  // The observer runs in the page (DevTools evaluation, not subject to the
  // page's CSP); it only looks for the marker's lines.
  await page.evaluate((marker) => {
    const seen = new Set();
    window.__delays = [];
    const pre = document.getElementById("frames");
    const needle = `  ${marker.padEnd(8, " ")}   [8]  `;
    new MutationObserver(() => {
      const now = (performance.timeOrigin + performance.now()) * 1000;
      const text = pre.textContent ?? "";
      let at = text.indexOf(needle);
      while (at >= 0) {
        const bytes = text.substr(at + needle.length, 23).split(" ");
        let us = 0;
        for (let i = 7; i >= 0; i--) us = us * 256 + parseInt(bytes[i], 16);
        if (!seen.has(us)) {
          seen.add(us);
          window.__delays.push(Math.round(now - us));
        }
        at = text.indexOf(needle, at + needle.length);
      }
    }).observe(pre, { childList: true, characterData: true, subtree: true });
  }, markerHex.toUpperCase());
  const cdp = profiling === "profile" ? await page.createCDPSession() : null;
  say("ready");
  for await (const line of rl) {
    if (line === "profile-start" && cdp) {
      await cdp.send("Profiler.enable");
      await cdp.send("Profiler.start");
    } else if (line === "report") {
      const top = cdp ? topFunctions((await cdp.send("Profiler.stop")).profile) : undefined;
      const r = await page.evaluate(() => ({
        delays_us: window.__delays,
        rate_text: document.getElementById("frames-rate")?.textContent ?? "",
        lost_text: document.getElementById("frames-lost")?.hidden
          ? ""
          : (document.getElementById("frames-lost")?.textContent ?? ""),
      }));
      say(JSON.stringify({ ...r, profile_top: top }));
    } else if (line.startsWith("show ")) {
      // Another page of the dashboard, for its CPU at demo traffic; said
      // back once the page is shown and has had a second to open its
      // streams and draw.
      const shown = line.slice(5);
      await page.evaluate((p) => {
        location.hash = p;
      }, shown);
      await page.waitForFunction(
        (p) => document.getElementById(`page-${p}`)?.hidden === false,
        { timeout: 30_000 },
        shown,
      );
      await new Promise((r) => setTimeout(r, 1000));
      say(`shown ${shown}`);
    } else if (line === "quit") {
      break;
    }
  }
} finally {
  rl.close();
  await browser.close();
}

/** The 15 functions with the most self time in a CPU profile, in ms. */
function topFunctions(profile) {
  const byId = new Map(profile.nodes.map((n) => [n.id, n]));
  const self = new Map();
  profile.samples.forEach((id, i) => {
    const f = byId.get(id).callFrame;
    const key = `${f.functionName || "(anonymous)"} ${f.url.split("/").pop()}:${f.lineNumber}:${f.columnNumber}`;
    self.set(key, (self.get(key) ?? 0) + (profile.timeDeltas[i] ?? 0) / 1000);
  });
  return [...self.entries()]
    .sort((a, b) => b[1] - a[1])
    .slice(0, 15)
    .map(([f, ms]) => [f, Math.round(ms)]);
}
