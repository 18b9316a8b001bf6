// Drives the dashboard in the system's headless Chromium (puppeteer-core)
// against a running gateway; started by tests/tests/dashboard_browser.rs,
// which owns the server and checks over gRPC what the page did.
//
//   node web/tests/dashboard.mjs demo URL SCREENSHOT_DIR
//   node web/tests/dashboard.mjs tokens URL SCREENSHOT_DIR VIEWER_TOKEN OPERATOR_TOKEN
//   node web/tests/dashboard.mjs tls https://127.0.0.1:PORT/ SCREENSHOT_DIR CERT_PEM
//   node web/tests/dashboard.mjs gone URL SCREENSHOT_DIR
//   node web/tests/dashboard.mjs layout URL SCREENSHOT_DIR
//   node web/tests/dashboard.mjs touch URL SCREENSHOT_DIR
//
// (gone: the test shuts the gateway down when asked, "need shutdown"; the
// page's failed requests after that are expected, not errors.)
//
// (tls: Chromium trusts the gateway's self-signed certificate CERT_PEM by
// its public key, --ignore-certificate-errors-spki-list, and no other.)
//
// Talks to the Rust test on stdout/stdin, one line each: "step NAME" when a
// step passed, "need send-frame" (or "need emcy", "need turn") and then it
// waits for a line on stdin (the test did it over gRPC; for "turn" the line
// is the wheel's statistics as GetHandwheel gives them once the turn has
// settled), "done" at the end. Any failure throws
// (exit status 1, the reason on stderr).
import puppeteer from "puppeteer-core";
import { createInterface } from "node:readline";
import { createHash, X509Certificate } from "node:crypto";
import { readFileSync } from "node:fs";

const [mode, url, shots, token, operatorToken] = process.argv.slice(2);
const chromium = process.env.CANGATE_CHROMIUM || "/usr/bin/chromium";
const WAIT = 30_000;
const rl = createInterface({ input: process.stdin });
const stdin = rl[Symbol.asyncIterator]();
function say(line) {
  process.stdout.write(line + "\n");
}

const browser = await puppeteer.launch({
  executablePath: chromium,
  headless: true,
  args: ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", ...tlsTrust()],
});
const errors = [];
let currentPage = null;
/** Set once the gateway is gone on purpose: its refused requests are expected. */
let gatewayGone = false;
try {
  const page = await browser.newPage();
  currentPage = page;
  await page.setViewport({ width: 1400, height: 800 });
  page.on("console", (m) => {
    if (m.type() === "error" && !gatewayGone) errors.push(`console: ${m.text()}`);
  });
  page.on("pageerror", (e) => errors.push(`page error: ${e.message}`));
  page.on("requestfailed", (r) => {
    // Streams the page ends itself (a new token restarts them) are aborted.
    if (r.failure()?.errorText !== "net::ERR_ABORTED" && !gatewayGone) {
      errors.push(`request failed: ${r.url()} ${r.failure()?.errorText}`);
    }
  });
  await page.goto(url, { waitUntil: "load" });
  if (mode === "demo") await demo(page);
  else if (mode === "tokens") await tokens(page);
  else if (mode === "tls") await tls(page);
  else if (mode === "gone") await gone(page);
  else if (mode === "layout") await layout(page);
  else if (mode === "touch") await touch(page);
  else if (mode === "health") await health(page);
  else throw new Error(`unknown mode ${mode}`);
  if (errors.length > 0) throw new Error(`the page reported errors:\n${errors.join("\n")}`);
  say("step no-console-errors");
  say("done");
} finally {
  // The open stdin would keep node running.
  rl.close();
  await browser.close();
}

// Function declarations (hoisted): the top-level code above calls them.
function cell(page, axis, cls) {
  return page.$eval(`.axis[data-axis="${axis}"] .${cls}`, (td) => td.textContent ?? "");
}
async function num(page, axis, cls) {
  return Number(await cell(page, axis, cls));
}
function sleep(ms) {
  return new Promise((r) => setTimeout(r, ms));
}

async function until(what, f, timeout = WAIT) {
  const end = Date.now() + timeout;
  for (;;) {
    const v = await f();
    if (v) return v;
    if (Date.now() > end) {
      const notice = await currentPage
        ?.$eval("#notice", (n) => (n.hidden ? "" : n.textContent))
        .catch(() => "");
      await currentPage?.screenshot({ path: `${shots}/failure-${mode}.png` }).catch(() => {});
      throw new Error(`timed out: ${what} (page notice: ${notice || "none"}; ${errors.join("; ")})`);
    }
    await sleep(25);
  }
}

/** X, Y and Z (the demo's CiA 402 axes) are listed (its CANsmc axes too). */
function axesListed(page) {
  return page.$$eval("#axes .axis", (rows) => {
    const names = rows.map((r) => r.dataset.axis);
    return ["X", "Y", "Z"].every((n) => names.includes(n));
  });
}

async function click(page, axis, cmd) {
  await press(page, `.axis[data-axis="${axis}"] button[data-cmd="${cmd}"]`);
}

// Clicks `sel` once it is visible, enabled and laid out where it stays
// (puppeteer's locator: a plain page.click measured a button while the
// layout changed, on a loaded host: "Node is either not clickable"). Timed
// out, it fails like `until`.
async function press(page, sel) {
  try {
    await page.locator(sel).setTimeout(WAIT).click();
  } catch (e) {
    await currentPage?.screenshot({ path: `${shots}/failure-${mode}.png` }).catch(() => {});
    throw new Error(`could not click ${sel}: ${e.message} (${errors.join("; ")})`);
  }
}

async function acquireAndEnable(page, axis) {
  await click(page, axis, "acquire");
  await until(`${axis} acquired`, async () =>
    (await page.$eval(`.axis[data-axis="${axis}"] button[data-cmd="acquire"]`, (b) => b.textContent)) === "Release");
  await click(page, axis, "enable");
  await until(`${axis} enabled`, async () => (await cell(page, axis, "state")) === "operation enabled");
}

async function demo(page) {
  await until("axes X, Y, Z listed", () => axesListed(page));
  say("step axes-listed");
  await page.screenshot({ path: `${shots}/axes.png` });

  // The demo's Y drive has a home switch at 0 (where it starts) and a
  // positive limit switch at 180 mm: their icons show, the home switch lit.
  const switches = async () =>
    page.$$eval(`.axis[data-axis="Y"] .switches`, (boxes) => {
      const box = boxes[0];
      if (!box || box.hidden) return null;
      const on = (name) => box.querySelector(`[data-switch="${name}"]`)?.dataset.active;
      return `home=${on("home")} positive=${on("positive-limit")} negative=${on("negative-limit")}`;
    });
  await until("Y's switch icons", async () => (await switches()) === "home=true positive=false negative=false");
  say(`step switches ${await switches()}`);

  // Enable, then move X to 12.5.
  await acquireAndEnable(page, "X");
  await page.$eval(`.axis[data-axis="X"] input[data-field="target"]`, (i) => { i.value = ""; });
  await page.type(`.axis[data-axis="X"] input[data-field="target"]`, "12.5");
  await click(page, "X", "move");
  await until("X at 12.5 on the page", async () =>
    Math.abs((await num(page, "X", "position")) - 12.5) < 0.002 && (await cell(page, "X", "activity")) === "idle");
  // The test checks over gRPC that X is there too.
  say("need x-at-12.5");
  await stdin.next();
  say("step x-moved");
  // The position trace (X is traced by default) went from 0 to 12.5.
  await until("the trace shows X's move", async () => {
    const d = await page.$eval("#trace-chart", (c) => ({ ...c.dataset, canvas: !!c.querySelector("canvas") }));
    return d.canvas && Math.abs(Number(d.min)) < 0.01 && Math.abs(Number(d.max) - 12.5) < 0.01;
  });
  say("step x-traced");
  await page.screenshot({ path: `${shots}/axes-x-moved.png` });

  // Hold jog+ on Y: it moves while held and stops after release.
  await acquireAndEnable(page, "Y");
  const y0 = await num(page, "Y", "position");
  const jog = await page.$(`.axis[data-axis="Y"] button[data-cmd="jog-plus"]`);
  const box = await jog.boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  await until("Y jogging", async () => (await cell(page, "Y", "activity")) === "jogging");
  // Held for longer than the dead-man time: the repeated Jog keeps it going.
  await sleep(1200);
  const yHeld = await num(page, "Y", "position");
  if (!((await cell(page, "Y", "activity")) === "jogging" && yHeld > y0 + 1)) {
    throw new Error(`Y stopped while the jog button was held (from ${y0} to ${yHeld})`);
  }
  await page.mouse.up();
  const released = Date.now();
  await until("Y at rest after release", async () =>
    (await cell(page, "Y", "activity")) === "idle" && Math.abs(await num(page, "Y", "velocity")) < 1e-6);
  say(`step y-jog held=${yHeld - y0} stop_ms=${Date.now() - released}`);
  const yRest = await num(page, "Y", "position");
  await sleep(300);
  if ((await num(page, "Y", "position")) !== yRest) throw new Error("Y moved on after the jog stopped");

  // Home X (the demo's method 35: here is home), then a move with the
  // velocity and acceleration given on the page.
  await click(page, "X", "home");
  await until("X homed", async () =>
    (await page.$eval(`.axis[data-axis="X"]`, (r) => r.dataset.homed)) === "true" && (await cell(page, "X", "activity")) === "idle");
  const xHome = await num(page, "X", "position");
  await setInput(page, `.axis[data-axis="X"] input[data-field="target"]`, String(xHome + 10));
  await setInput(page, `.axis[data-axis="X"] input[data-field="velocity"]`, "20");
  await setInput(page, `.axis[data-axis="X"] input[data-field="acceleration"]`, "200");
  await click(page, "X", "move");
  await until("X moving", async () => (await cell(page, "X", "activity")) === "moving");
  let vmax = 0;
  await until("X 10 further at rest", async () => {
    vmax = Math.max(vmax, Math.abs(await num(page, "X", "velocity")));
    return (await cell(page, "X", "activity")) === "idle" && Math.abs((await num(page, "X", "position")) - xHome - 10) < 0.002;
  });
  say(`step home-move home=${xHome} vmax=${vmax}`);
  await setInput(page, `.axis[data-axis="X"] input[data-field="velocity"]`, "");
  await setInput(page, `.axis[data-axis="X"] input[data-field="acceleration"]`, "");

  // STOP ALL stops a long move of X.
  await page.$eval(`.axis[data-axis="X"] input[data-field="target"]`, (i) => { i.value = ""; });
  await page.type(`.axis[data-axis="X"] input[data-field="target"]`, "-150");
  await click(page, "X", "move");
  await until("X moving", async () => (await cell(page, "X", "activity")) === "moving");
  await sleep(200);
  await press(page, "#stop-all");
  await until("X stopped by STOP ALL", async () =>
    (await cell(page, "X", "activity")) === "idle" && Math.abs(await num(page, "X", "velocity")) < 1e-6);
  const xStopped = await num(page, "X", "position");
  if (!(xStopped < 12.5 && xStopped > -140)) throw new Error(`X not stopped mid-way: ${xStopped}`);
  say(`step stop-all x=${xStopped}`);

  // The live frame view shows a frame the test sends over gRPC.
  await press(page, `button[data-page="buses"]`);
  await until("can0 listed", () => page.$(`#buses tr[data-bus="can0"]`));
  await until("frames arriving", async () => (await page.$eval("#frames", (p) => p.textContent ?? "")).length > 0);
  // A candump-style filter for 0x7E5 only: the view empties, then shows
  // exactly the frame the test sends.
  await setFilter(page, "7E5:7FF");
  await until("the filtered view empty", async () => (await page.$eval("#frames", (p) => p.textContent)) === "");
  // The view empties at once, but the filtered stream may not be open yet
  // on a busy host, and a frame sent before it is not shown: asked again
  // (the test sends another) until the view holds the sent frame and
  // nothing else.
  const sentShown = async () => {
    const lines = (await page.$eval("#frames", (p) => p.textContent ?? "")).split("\n").filter((l) => l);
    return lines.length > 0 && lines.every((l) => l === "can0  7E5        [3]  C0 FF EE");
  };
  for (let asked = 1; ; asked++) {
    say("need send-frame");
    await stdin.next();
    const end = Date.now() + 2000;
    while (!(await sentShown()) && Date.now() < end) await sleep(25);
    if (await sentShown()) break;
    if (asked === 5) await until("the sent frame shown", sentShown);
  }
  say("step frame-shown");
  // Node 1's TPDO1 only; then everything but it (inverted). (The view
  // shows received frames: the gateway's own SYNC is not among them.)
  const ids = async () =>
    (await page.$eval("#frames", (p) => p.textContent ?? "")).split("\n").filter((l) => l).map((l) => l.slice(6, 14).trim());
  await setFilter(page, "181:7FF");
  await until("only 181 frames", async () => { const i = await ids(); return i.length >= 3 && i.every((x) => x === "181"); });
  await setFilter(page, "181~7FF");
  await until("frames but none of 181", async () => {
    const i = await ids();
    return i.length >= 20 && !i.includes("181") && i.includes("182");
  });
  await setFilter(page, "12G:7FF");
  await until("a bad filter refused", async () => (await text(page, "#frames-filter-error")).includes("12G:7FF"));
  await setFilter(page, "");
  await until("181 back unfiltered", async () => (await ids()).includes("181"));
  say("step filters");
  // The load chart has a series per bus; its latest point is the table's.
  await until("a few load points", async () => Number(await page.$eval("#load-chart", (c) => c.dataset.points)) >= 3);
  const load = await page.$eval("#load-chart", (c) => JSON.parse(c.dataset.last));
  const table = await page.$$eval("#buses tbody tr", (rows) => rows.map((r) => Number(r.children[2].textContent)));
  if (load.length !== table.length || load.some((v, i) => Math.abs(v - table[i]) > 0.051)) {
    throw new Error(`load chart ${load} and table ${table} differ`);
  }
  say(`step load-chart can0=${load[0]}`);
  await page.screenshot({ path: `${shots}/buses.png` });

  await canopenPage(page);
  await handwheelPage(page);
  await cansmcPage(page);
  const most = await page.$eval("body", (b) => Number(b.dataset.streamsMax));
  if (!(most >= 2 && most <= 3)) throw new Error(`the page held ${most} streams at once (at most 3)`);
  say(`step streams max=${most}`);
  await leaveThePage(page);
}

// Leaving the page (a reload, a closed tab) gives its leases back at once
// instead of letting them lapse (3 s): the test checks over gRPC that X is
// free well within that.
async function leaveThePage(page) {
  const held = await page.$eval('.axis[data-axis="X"] .control', (td) => td.textContent ?? "");
  if (held !== "this page") throw new Error(`X's control before leaving: ${held}`);
  await page.goto("about:blank");
  say("need lease-released");
  await stdin.next();
  say("step lease-released");
}

function nodeCell(page, node, cls) {
  return page.$eval(`#nodes tr[data-bus="can0"][data-node="${node}"] td.${cls}`, (td) => td.textContent ?? "");
}
function text(page, sel) {
  return page.$eval(sel, (e) => (e.hidden ? "" : e.textContent ?? ""));
}

async function canopenPage(page) {
  await press(page, `button[data-page="canopen"]`);
  // The demo's nodes, operational, with heartbeats and identities.
  // (The boot procedure starts the drives, the I/O node and the handwheel.)
  await until("CANopen nodes 1, 2, 3, 4 and 10 operational", async () => {
    const nmt = await page.$$eval("#nodes tbody tr", (rows) =>
      Object.fromEntries(rows.filter((r) => r.dataset.bus === "can0").map((r) => [r.dataset.node, r.dataset.nmt])));
    return ["1", "2", "3", "4", "10"].every((n) => nmt[n] === "operational");
  });
  const hb = await nodeCell(page, 1, "hb");
  const age = Number(hb.replace(/ ms.*/, ""));
  if (!(age >= 0 && age < 1000)) throw new Error(`node 1 heartbeat age ${hb}`);
  const identity = await nodeCell(page, 1, "identity");
  if (!/vendor 0x[0-9A-F]{8} product 0x[0-9A-F]{8} rev 0x[0-9A-F]{8} serial \d+/.test(identity)) {
    throw new Error(`node 1 identity ${identity}`);
  }
  say(`step canopen-nodes identity=${JSON.stringify(identity)}`);

  // NMT: put the I/O node (3) in pre-operational, stop it, and start it
  // again.
  await press(page, `#nodes tr[data-node="3"] button[data-cmd="nmt-enter_pre_operational"]`);
  await until("node 3 pre-operational", async () => (await nodeCell(page, 3, "nmt")) === "pre operational");
  await press(page, `#nodes tr[data-node="3"] button[data-cmd="nmt-stop"]`);
  await until("node 3 stopped", async () => (await nodeCell(page, 3, "nmt")) === "stopped");
  await press(page, `#nodes tr[data-node="3"] button[data-cmd="nmt-start"]`);
  await until("node 3 operational again", async () => (await nodeCell(page, 3, "nmt")) === "operational");
  await until("the NMT changes in the event log", async () => {
    const log = await text(page, "#node-events");
    return ["operational → pre operational", "pre operational → stopped", "stopped → operational"].every((c) =>
      log.includes(`can0 node 3: NMT ${c}`));
  });
  say("step nmt");

  // An EMCY (sent by the simulated node 4 on the test's request) appears
  // in the history and the event log.
  say("need emcy");
  await stdin.next();
  await until("the EMCY shown", async () =>
    (await text(page, "#emcy-history")).includes("can0 node 4: 0x2310") &&
    (await text(page, "#node-events")).includes("can0 node 4: EMCY 0x2310"));
  say(`step emcy-shown ${JSON.stringify(await nodeCell(page, 4, "fault"))}`);

  // The EMCY is an alarm: counted in the header on every page, listed with
  // its source, kept until acknowledged.
  const count = () => page.$eval("#alarm-count", (c) => (c.hidden ? 0 : Number(c.textContent)));
  await until("the alarm counted in the header", async () => (await count()) >= 1);
  await press(page, `button[data-page="alarms"]`);
  const emcyAlarm = `#alarms tr[data-source="can0 node 4"]`;
  await until("the EMCY alarm listed", async () =>
    (await page.$$eval(emcyAlarm, (rows) =>
      rows.some((r) => r.dataset.state === "active" && r.textContent.includes("EMCY 0x2310")))));
  const before = await count();
  await press(page, `${emcyAlarm}.active button[data-cmd="acknowledge"]`);
  await until("the EMCY alarm acknowledged", async () =>
    (await page.$$eval(emcyAlarm, (rows) => rows.every((r) => r.dataset.state.startsWith("acknowledged")))) &&
    (await count()) === before - 1);
  await page.screenshot({ path: `${shots}/alarms.png` });
  say(`step alarm-emcy count-before=${before}`);

  // The pages not shown are not drawn: the axes' statuses (the demo's
  // CANsmc axes send one per cycle) and the buses' poll (every second) keep
  // coming, yet nothing in the axes or buses page changes while the alarms
  // page is shown. (Watched for 2.5 s: the page drew them within one poll.)
  const hiddenChanges = await page.evaluate(async () => {
    const seen = [];
    const watch = new MutationObserver((records) => {
      for (const r of records) seen.push(`${r.type} ${r.target.nodeName}${r.attributeName ? ` ${r.attributeName}` : ""}`);
    });
    for (const id of ["page-axes", "page-buses"]) {
      watch.observe(document.getElementById(id), { subtree: true, childList: true, attributes: true, characterData: true });
    }
    await new Promise((r) => setTimeout(r, 2500));
    watch.disconnect();
    return seen;
  });
  if (hiddenChanges.length > 0) {
    throw new Error(`hidden pages drawn ${hiddenChanges.length} times: ${[...new Set(hiddenChanges)].slice(0, 5).join("; ")}`);
  }
  say("step hidden-pages-still");
  await press(page, `button[data-page="canopen"]`);

  // SDO read of 0x1008 (device name) of node 1, with the EDS type.
  await page.select("#sdo-node", "can0/1");
  await setInput(page, "#sdo-index", "1008");
  await setInput(page, "#sdo-sub", "0");
  await page.select("#sdo-type", "0");
  await press(page, "#sdo-read");
  await until("the SDO read shown", async () =>
    (await page.$eval("#sdo-result", (e) => e.dataset.outcome)) === "ok");
  say(`step sdo-read ${await text(page, "#sdo-result")}`);

  // A write to the read-only 0x1000 (device type): the node's abort,
  // with its code and CiA 301 name.
  await setInput(page, "#sdo-index", "1000");
  await setInput(page, "#sdo-value", "1");
  await press(page, "#sdo-write");
  await until("the SDO abort shown", async () => (await text(page, "#sdo-abort")) !== "");
  if ((await page.$eval("#sdo-result", (e) => e.dataset.outcome)) !== "error") throw new Error("the write was not refused");
  say(`step sdo-abort ${await text(page, "#sdo-abort")}`);
  await sdoByName(page);
  await canopenScan(page);
  await page.screenshot({ path: `${shots}/canopen.png` });
}

/**
 * The SDO panel's object picker (ListObjects of node 1): "device name"
 * found by name, picked, its EDS type preselected, read by name; then
 * "1017" found by index (one match: picked by itself). Reports the read's
 * result, the picked object's facts and the object found by index.
 */
async function sdoByName(page) {
  await page.select("#sdo-node", "can0/1");
  await setInput(page, "#sdo-search", "device name");
  const name = "Manufacturer device name";
  await until(`${name} offered by the picker`, async () =>
    (await page.$$eval("#sdo-object option", (os) => os.map((o) => o.value))).includes(name));
  await page.select("#sdo-object", name);
  const type = await page.$eval("#sdo-type", (s) => s.selectedOptions[0]?.textContent ?? "");
  if (!type.includes("VISIBLE_STRING")) throw new Error(`the EDS type was not preselected: ${type}`);
  await press(page, "#sdo-read");
  await until("the read by name shown", async () =>
    (await text(page, "#sdo-result")).startsWith(`read can0 node 1 "${name}"`) &&
    (await page.$eval("#sdo-result", (e) => e.dataset.outcome)) === "ok");
  const result = await text(page, "#sdo-result");
  const info = await text(page, "#sdo-object-info");
  await setInput(page, "#sdo-search", "1017");
  await until("0x1017 found by index", async () => (await page.$eval("#sdo-object", (s) => s.value)) !== "");
  const byIndex = await page.$eval("#sdo-object", (s) => s.value);
  say(`step sdo-read-by-name ${result} | ${info} | ${byIndex}`);
}

/** Scan network on can0: the nodes that answered, by id (compared with ScanNetwork over gRPC). */
async function canopenScan(page) {
  await page.select("#scan-bus", "can0");
  await press(page, "#scan");
  await until("the scan's nodes listed", async () =>
    (await page.$eval("#scan-result", (u) => u.dataset.bus ?? "")) === "can0");
  const ids = await page.$$eval("#scan-result li", (li) => li.map((l) => Number(l.dataset.node)));
  if (ids.length === 0) throw new Error(`the scan found nothing: ${await text(page, "#scan-status")}`);
  say(`step canopen-scan ${JSON.stringify(ids)}`);
}

function wheelStats(page) {
  return page.$$eval(`section[data-handwheel="hw1"] tr[data-key]`, (rows) =>
    Object.fromEntries(rows.map((r) => [r.dataset.key, r.querySelector("td").textContent])));
}

async function handwheelPage(page) {
  await press(page, `button[data-page="handwheel"]`);
  await until("hw1 shown", () => page.$(`section[data-handwheel="hw1"] tr[data-key="frames"]`));
  await press(page, `section[data-handwheel="hw1"] button[data-cmd="mode-manual"]`);
  await until("hw1 in manual mode", async () =>
    (await page.$eval(`section[data-handwheel="hw1"]`, (c) => c.dataset.mode)) === "manual");
  // The test turns the simulated wheel with random frame loss, waits for
  // the gateway's counters to settle and says what they are.
  say("need turn");
  const want = JSON.parse((await stdin.next()).value);
  await until("the page's counters are the gateway's", async () => {
    const got = await wheelStats(page);
    return Object.entries(want).every(([k, v]) => got[k] === String(v));
  });
  await until("every feed frame in the live feed", async () =>
    (await text(page, "#feed")).split("\n").filter((l) => l.includes("  hw1  X+")).length === want.frames);
  const feed = await text(page, "#feed");
  const compensatedLines = feed.split("\n").filter((l) => l.includes("compensated")).length;
  say(`step handwheel ${JSON.stringify(await wheelStats(page))} compensated_lines=${compensatedLines}`);
  await page.screenshot({ path: `${shots}/handwheel.png` });
  await press(page, `section[data-handwheel="hw1"] button[data-cmd="mode-automatic"]`);
  await until("hw1 in automatic mode", async () =>
    (await page.$eval(`section[data-handwheel="hw1"]`, (c) => c.dataset.mode)) === "automatic");
  say("step handwheel-automatic");
}

async function cansmcPage(page) {
  await press(page, `button[data-page="cansmc"]`);
  await until("the CANsmc master in P2 with its slaves operational", async () => {
    const phase = await page.$eval("#cansmc-master", (b) => b.dataset.phase);
    const states = await page.$$eval("#cansmc-slaves tbody tr", (rows) => rows.map((r) => r.dataset.state));
    return phase === "p2" && states.length > 0 && states.every((s) => s === "operational");
  });
  const dts = () => page.$$eval("#cansmc-slaves tbody tr", (rows) => rows.map((r) => Number(r.dataset.dts)));
  const first = await dts();
  await until("DT counters going up", async () => (await dts()).every((d, i) => d > first[i]));
  const j = await page.$$eval("#cansmc-jitter .jrow", (rows) => Object.fromEntries(rows.map((r) => [r.dataset.stat, Number(r.dataset.us)])));
  if (!(j.p50 <= j.p99 && j.p99 <= j["p99.9"] && j["p99.9"] <= j.max)) throw new Error(`jitter ${JSON.stringify(j)}`);
  const slaves = await page.$$eval("#cansmc-slaves tbody tr", (rows) =>
    rows.map((r) => `${r.dataset.address}:${r.children[1].textContent}`));
  say(`step cansmc ${JSON.stringify(slaves)}`);
  await cansmcHistogram(page);
  await page.screenshot({ path: `${shots}/cansmc.png` });
  await cansmcRestart(page);
  await cansmcParameters(page);
}

/** The MST jitter histogram is drawn: its bars sum to the samples of the same status, and the canvas has them. */
async function cansmcHistogram(page) {
  const h = () => page.$eval("#cansmc-histogram", (c) => ({ ...c.dataset }));
  await until("the jitter histogram drawn", async () => Number((await h()).drawn) > 0);
  const d = await h();
  if (!(d.total === d.samples && Number(d.samples) > 0)) throw new Error(`histogram ${JSON.stringify(d)}`);
  // Bars on the canvas: pixels of the bars' colour.
  const blue = await page.$eval("#cansmc-histogram", (c) => {
    const px = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
    let n = 0;
    for (let i = 0; i < px.length; i += 4) if (px[i] === 0x4c && px[i + 1] === 0x8d && px[i + 2] === 0xf6) n++;
    return n;
  });
  if (blue === 0) throw new Error("no bars on the histogram's canvas");
  say(`step cansmc-histogram samples=${d.samples} total=${d.total} buckets=${d.buckets} bucket_us=${d.bucketUs} drawn=${d.drawn}`);
}

/** Restart (asked twice) takes the master through P0 and P1 back to P2. */
async function cansmcRestart(page) {
  const starts = Number(await page.$eval("#cansmc-master", (b) => b.dataset.starts));
  await press(page, "#cansmc-restart");
  await until("the restart asks for confirmation", async () =>
    (await page.$eval("#cansmc-restart", (b) => b.dataset.armed)) === "true");
  await press(page, "#cansmc-restart");
  await until("the master restarted and back in P2", async () => {
    const b = await page.$eval("#cansmc-master", (m) => ({ ...m.dataset }));
    return Number(b.starts) === starts + 1 && b.phase === "p2";
  });
  const log = await text(page, "#cansmc-events");
  const at = (p) => log.indexOf(`  phase ${p}`);
  if (!(at("P0") >= 0 && at("P0") < at("P1") && at("P1") < log.lastIndexOf("  phase P2"))) {
    throw new Error(`phases not P0, P1, P2 in the events:\n${log}`);
  }
  await until("the slaves operational again", async () => {
    const states = await page.$$eval("#cansmc-slaves tbody tr", (rows) => rows.map((r) => r.dataset.state));
    return states.length > 0 && states.every((s) => s === "operational");
  });
  say(`step cansmc-restart starts=${starts + 1}`);
}

/** Parameters: read 3 (read-only), a write of 3 refused, a write of 4 confirmed (read back over gRPC by the test). */
async function cansmcParameters(page) {
  const result = async () => page.$eval("#param-result", (r) => ({ ...r.dataset, text: r.textContent }));
  const run = async (button) => {
    await page.$eval("#param-result", (r) => { delete r.dataset.outcome; });
    await press(page, button);
    await until(`${button} answered`, async () => (await result()).outcome !== undefined);
    return result();
  };
  await page.select("#param-slave", "1");
  await setInput(page, "#param-number", "3");
  const res = await run("#param-read");
  if (res.outcome !== "ok") throw new Error(`read of parameter 3: ${res.text}`);
  await setInput(page, "#param-value", "5");
  const refused = await run("#param-write");
  if (refused.outcome !== "error" || !refused.text.includes("FailedPrecondition")) throw new Error(`write of 3: ${refused.text}`);
  await setInput(page, "#param-number", "4");
  await setInput(page, "#param-value", "23456");
  const written = await run("#param-write");
  if (written.outcome !== "ok" || written.value !== "23456") throw new Error(`write of 4: ${written.text}`);
  say(`step cansmc-parameters resolution=${res.value} refused=${JSON.stringify(refused.text)} written=${written.value}`);
  await page.screenshot({ path: `${shots}/cansmc-parameters.png` });
}

async function setFilter(page, value) {
  await page.$eval("#frames-filter", (i, v) => {
    i.value = v;
    i.dispatchEvent(new Event("change"));
  }, value);
}

async function setInput(page, sel, value) {
  await page.$eval(sel, (i) => { i.value = ""; });
  await page.type(sel, value);
}

async function tokens(page) {
  await until("the page asks for a token", async () =>
    (await page.$eval("#conn", (c) => c.textContent)) === "token needed");
  const rows = await page.$$eval("#axes .axis", (r) => r.length);
  if (rows !== 0) throw new Error("axes listed without a token");
  say("step refused-without-token");
  await page.screenshot({ path: `${shots}/token-needed.png` });
  await page.type("#token", token);
  await press(page, "#token-use");
  await until("axes listed with the token", () => axesListed(page));
  await until("connected", async () => (await page.$eval("#conn", (c) => c.textContent)) === "connected");
  say("step accepted-with-token");
  // A viewer may watch but not take control: the page shows the role and
  // disables what it may not use, saying why.
  await until("the role shown", async () => (await text(page, "#role")).startsWith("role: viewer"));
  say(`step role ${await text(page, "#role")}`);
  say(`step viewer-buttons ${JSON.stringify(await buttonStates(page))}`);
  await page.screenshot({ path: `${shots}/token-viewer.png` });

  // An operator may take control and stop, but not send NMT or write SDO.
  await page.type("#token", operatorToken);
  await press(page, "#token-use");
  await until("the operator's role shown", async () => (await text(page, "#role")).startsWith("role: operator"));
  await until("axes listed again", () => axesListed(page));
  say(`step role ${await text(page, "#role")}`);
  await click(page, "X", "acquire");
  await until("X acquired by the operator", async () =>
    (await page.$eval(`.axis[data-axis="X"] button[data-cmd="acquire"]`, (b) => b.textContent)) === "Release");
  say(`step operator-buttons ${JSON.stringify(await buttonStates(page))}`);
  await click(page, "X", "acquire");
  await until("X released", async () =>
    (await page.$eval(`.axis[data-axis="X"] button[data-cmd="acquire"]`, (b) => b.textContent)) === "Acquire");
  await page.screenshot({ path: `${shots}/token-operator.png` });
}

/** Disabled buttons' tooltips (or "enabled") of a few buttons the roles tell apart. */
async function buttonStates(page) {
  await press(page, `button[data-page="canopen"]`);
  await until("nodes listed", () => page.$(`#nodes tr[data-node="1"]`));
  const state = (sel) => page.$eval(sel, (b) => (b.disabled ? b.title : "enabled"));
  const out = {
    acquire: await state(`.axis[data-axis="X"] button[data-cmd="acquire"]`),
    enable: await state(`.axis[data-axis="X"] button[data-cmd="enable"]`),
    stopAll: await state("#stop-all"),
    nmt: await state(`#nodes tr[data-node="1"] button[data-cmd="nmt-start"]`),
    sdoRead: await state("#sdo-read"),
    sdoWrite: await state("#sdo-write"),
    scan: await state("#scan"),
    smcRestart: await state("#cansmc-restart"),
    paramRead: await state("#param-read"),
    paramWrite: await state("#param-write"),
  };
  await press(page, `button[data-page="axes"]`);
  return out;
}

/** Chromium's flag trusting the certificate of the tls mode by its SPKI (base64 SHA-256), or nothing. */
function tlsTrust() {
  if (mode !== "tls") return [];
  const cert = new X509Certificate(readFileSync(token));
  const spki = cert.publicKey.export({ type: "spki", format: "der" });
  return [`--ignore-certificate-errors-spki-list=${createHash("sha256").update(spki).digest("base64")}`];
}

/** The page over HTTPS: loaded, axes listed over gRPC-Web on TLS (HTTP/2, the gateway's ALPN). */
async function tls(page) {
  const protocol = await page.evaluate(() => location.protocol);
  if (protocol !== "https:") throw new Error(`loaded over ${protocol}`);
  await until("axes X, Y, Z listed over TLS", () => axesListed(page));
  await until("connected", async () => (await page.$eval("#conn", (c) => c.textContent)) === "connected");
  const axes = await page.$$eval("#axes .axis", (rows) => rows.map((r) => r.dataset.axis));
  // How the gRPC-Web calls went: the resource timing's protocol.
  const hops = await page.evaluate(() => [
    ...new Set(
      performance
        .getEntriesByType("resource")
        .filter((e) => e.name.includes("/cangate.v1."))
        .map((e) => e.nextHopProtocol),
    ),
  ]);
  say(`step tls-axes ${JSON.stringify(axes)} protocol=${hops.join(",")}`);
  await page.screenshot({ path: `${shots}/tls.png` });
}

// The Control column follows the handwheel taking and releasing X; quick
// stop of every axis; then the gateway goes away: the connection line
// turns, the rows are marked stale with their age, and a STOP ALL that
// fails stays on the page until acknowledged.
async function gone(page) {
  await until("axes X, Y, Z listed", () => axesListed(page));
  await until("connected", async () => (await page.$eval("#conn", (c) => c.textContent)) === "connected");
  const control = () => cell(page, "X", "control");
  await press(page, `button[data-page="handwheel"]`);
  await until("hw1 shown", () => page.$(`section[data-handwheel="hw1"] tr[data-key="frames"]`));
  await press(page, `section[data-handwheel="hw1"] button[data-cmd="mode-manual"]`);
  await until("X's control shows the handwheel", async () => (await control()).includes("handwheel hw1"));
  say(`step control-taken ${await control()}`);
  await press(page, `section[data-handwheel="hw1"] button[data-cmd="mode-automatic"]`);
  await until("X's control free again", async () => (await control()) === "—");
  say("step control-released");
  await press(page, `button[data-page="axes"]`);

  // Quick stop of every axis (at rest: nothing to do, nothing refused).
  await press(page, "#quick-stop-all");
  await sleep(500);
  const banner = await page.$eval("#stop-failed", (b) => (b.hidden ? "" : b.textContent));
  if (banner) throw new Error(`quick stop all failed: ${banner}`);
  say("step quick-stop-all");

  say("need shutdown");
  await stdin.next();
  gatewayGone = true;
  const t0 = Date.now();
  await until("the connection line turns", async () =>
    (await page.$eval("body", (b) => b.dataset.conn)) === "lost");
  say(`step link-lost ms=${Date.now() - t0} ${await page.$eval("#conn", (c) => c.textContent)}`);
  await until("every axis row marked stale with its age", async () => {
    const rows = await page.$$eval("#axes .axis", (rs) =>
      rs.map((r) => [r.dataset.stale, r.querySelector(".stale-age")?.textContent ?? ""]));
    return rows.length > 0 && rows.every(([stale, age]) => stale === "true" && /^stale \d+ s$/.test(age));
  });
  // The age counts up.
  await until("the age counts up", async () =>
    (await page.$eval('.axis[data-axis="X"] .stale-age', (a) => a.textContent)) !== "stale 0 s");
  say(`step rows-stale ${await page.$eval('.axis[data-axis="X"] .stale-age', (a) => a.textContent)}`);
  await page.screenshot({ path: `${shots}/gone.png` });

  await press(page, "#stop-all");
  const failed = () => page.$eval("#stop-failed", (b) => (b.hidden ? "" : b.textContent));
  await until("the failed STOP ALL shown", async () => (await failed()).includes("STOP ALL FAILED"));
  // Still there after other messages came and went.
  await until("the notice changed since", async () => (await text(page, "#notice")) !== "");
  await sleep(1500);
  if (!(await failed()).includes("STOP ALL FAILED")) throw new Error("the failed stop was not kept");
  say("step stop-failed-shown");
  await press(page, "#stop-failed-ack");
  await until("the failed stop acknowledged", async () => (await failed()) === "");
  say("step stop-failed-acknowledged");
}

// Every page at a panel PC's 1024×768 and at 1920×1080, and the axes view
// on an upright tablet (768×1024): no command button
// lies outside the viewport's width, the page never scrolls sideways, and
// no number is cut (its scrollWidth fits its clientWidth). Screenshots of
// every page at both sizes.
async function layout(page) {
  await until("axes X, Y, Z listed", () => axesListed(page));
  // Every page on a panel PC and a full HD screen; the axes view also on
  // a tablet held upright.
  const sizes = [
    [1024, 768, ["axes", "buses", "canopen", "handwheel", "cansmc", "alarms"]],
    [1920, 1080, ["axes", "buses", "canopen", "handwheel", "cansmc", "alarms"]],
    [768, 1024, ["axes"]],
  ];
  for (const [width, height, tabs] of sizes) {
    await page.setViewport({ width, height });
    for (const tab of tabs) {
      await press(page, `button[data-page="${tab}"]`);
      // Its first data in: a row, a card, or a master's line.
      await until(`${tab} filled`, () =>
        page.$eval(`#page-${tab}`, (s) =>
          s.querySelectorAll("tbody tr, .axis, .card, [data-phase], #alarms").length > 0));
      await sleep(300);
      const bad = await page.evaluate((tab) => {
        const problems = [];
        const w = document.documentElement.clientWidth;
        if (document.documentElement.scrollWidth > w + 1) {
          problems.push(`the page scrolls sideways (${document.documentElement.scrollWidth} > ${w})`);
        }
        const shown = (e) => e.offsetParent !== null && e.getClientRects().length > 0;
        const scope = [document.querySelector("header"), document.getElementById(`page-${tab}`)];
        for (const root of scope) {
          for (const b of root.querySelectorAll("button")) {
            if (!shown(b)) continue;
            const r = b.getBoundingClientRect();
            if (r.left < -1 || r.right > w + 1) {
              problems.push(`button "${b.textContent}" at x ${Math.round(r.left)}..${Math.round(r.right)} (viewport ${w})`);
            }
          }
          for (const n of root.querySelectorAll(".num, td.num")) {
            if (!shown(n)) continue;
            if (n.scrollWidth > n.clientWidth + 1) {
              problems.push(`number "${n.textContent}" cut (${n.scrollWidth} > ${n.clientWidth})`);
            }
          }
        }
        for (const id of ["stop-all", "quick-stop-all"]) {
          const r = document.getElementById(id).getBoundingClientRect();
          if (r.top < 0 || r.bottom > window.innerHeight || r.right > w + 1) problems.push(`${id} not in view`);
        }
        return problems;
      }, tab);
      await page.screenshot({ path: `${shots}/${tab}-${width}x${height}.png` });
      if (bad.length > 0) throw new Error(`${tab} at ${width}×${height}: ${bad.join("; ")}`);
      say(`step layout ${tab} ${width}x${height}`);
    }
  }
}

// Hold-to-run with a finger on a touch panel: Y jogs while the jog button
// is touched (longer than the dead-man time), stops when the finger lifts,
// and stops when the touch is lost (touchcancel: the panel took the
// gesture, the finger slid off the glass).
/**
 * Alarms from the polled states: the test takes smc1 off the bus (the
 * CANsmc status channel), the page lists the bus-off and the loss of the
 * spindle encoder (a slave no axis reports for), and marks both cleared
 * once the bus is back.
 */
async function health(page) {
  await press(page, `button[data-page="alarms"]`);
  const rows = (source, f) => page.$$eval(`#alarms tr[data-source="${source}"]`, f);
  const bus = "bus smc1";
  const encoder = "CANsmc smc slave 3 (Spindle encoder)";
  say("need smc1-bus-off");
  await stdin.next();
  await until("the bus-off alarm", () =>
    rows(bus, (rs) => rs.some((r) => r.dataset.state === "active" && r.textContent.includes("bus-off"))));
  await until("the spindle encoder's loss", () =>
    rows(encoder, (rs) => rs.some((r) => r.dataset.state === "active" && r.textContent.includes("slave lost"))));
  await page.screenshot({ path: `${shots}/alarms-bus-off.png` });
  say("step health-raised");
  say("need smc1-recover");
  await stdin.next();
  for (const source of [bus, encoder]) {
    await until(`${source}'s alarm cleared`, () =>
      rows(source, (rs) => rs.length > 0 && rs.every((r) => r.dataset.state === "cleared")));
  }
  say("step health-cleared");
}

async function touch(page) {
  await page.setViewport({ width: 1024, height: 768, hasTouch: true });
  await until("axes X, Y, Z listed", () => axesListed(page));
  await acquireAndEnable(page, "Y");
  const jog = await page.$(`.axis[data-axis="Y"] button[data-cmd="jog-plus"]`);
  await jog.scrollIntoView();
  const box = await jog.boundingBox();
  const [x, y] = [box.x + box.width / 2, box.y + box.height / 2];
  const cdp = await page.createCDPSession();
  const finger = (type) =>
    cdp.send("Input.dispatchTouchEvent", { type, touchPoints: type === "touchStart" ? [{ x, y }] : [] });
  const jogging = async () => (await cell(page, "Y", "activity")) === "jogging";
  const atRest = async () =>
    (await cell(page, "Y", "activity")) === "idle" && Math.abs(await num(page, "Y", "velocity")) < 1e-6;

  for (const end of ["touchEnd", "touchCancel"]) {
    const y0 = await num(page, "Y", "position");
    await finger("touchStart");
    await until(`Y jogging under the finger (${end})`, jogging);
    await sleep(1200);
    const held = await num(page, "Y", "position");
    if (!((await jogging()) && held > y0 + 1)) {
      throw new Error(`Y stopped while touched (from ${y0} to ${held})`);
    }
    await finger(end);
    const t0 = Date.now();
    await until(`Y at rest after ${end}`, atRest);
    say(`step touch ${end} moved=${(held - y0).toFixed(1)} stop_ms=${Date.now() - t0}`);
  }
}
