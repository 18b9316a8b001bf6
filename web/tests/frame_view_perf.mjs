// Measures the dashboard's live frame view under load, in the system's
// headless Chromium (puppeteer-core); started by the bench binary
// `dashboard_bench`, which owns the gateway, loads its bus, and reads the
// browser's CPU time from /proc.
//
//   node web/tests/frame_view_perf.mjs URL MARKER_ID_HEX
//
// Opens URL#buses (the live view of the first bus) and watches the view's
// text: each line of the marker identifier carries, in its 8 data bytes
// (little-endian), the time the bench put it on the bus, in µs since the
// epoch; the delay is the time the line is first on the screen (the view's
// text replaced, after the page's rendering) minus that. Protocol on
// stdout/stdin, a line each: "ready" once the view streams; then on stdin
// "report" -> one JSON line {"delays_us": [...], "rate_text": "...",
// "lost_text": "..."}; on "quit" it exits.
import puppeteer from "puppeteer-core";
import { createInterface } from "node:readline";

const [url, markerHex] = process.argv.slice(2);
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
  say("ready");
  for await (const line of rl) {
    if (line === "report") {
      const r = await page.evaluate(() => ({
        delays_us: window.__delays,
        rate_text: document.getElementById("frames-rate")?.textContent ?? "",
        lost_text: document.getElementById("frames-lost")?.hidden
          ? ""
          : (document.getElementById("frames-lost")?.textContent ?? ""),
      }));
      say(JSON.stringify(r));
    } else if (line === "quit") {
      break;
    }
  }
} finally {
  rl.close();
  await browser.close();
}
