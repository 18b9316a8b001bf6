// Bundles the dashboard into dist/ (app.js, app.css, index.html), which the
// server embeds (server/src/web.rs). Deterministic: no source maps, no
// timestamps, so that the test command can compare a fresh build with the
// committed one byte for byte.
import * as esbuild from "esbuild";
import { copyFileSync, mkdirSync } from "node:fs";

mkdirSync("dist", { recursive: true });
await esbuild.build({
  entryPoints: { app: "src/main.ts" },
  bundle: true,
  minify: true,
  format: "iife",
  target: ["chrome110", "firefox110", "safari16"],
  outdir: "dist",
  legalComments: "none",
  logLevel: "warning",
});
await esbuild.build({
  entryPoints: { app: "src/style.css" },
  bundle: true,
  minify: true,
  outdir: "dist",
  logLevel: "warning",
});
copyFileSync("src/index.html", "dist/index.html");
