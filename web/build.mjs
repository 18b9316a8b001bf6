// Bundles the dashboard into dist/ (app.js, app.css, index.html), which the
// server embeds (server/src/web.rs). Deterministic: no source maps, no
// timestamps, so that the test command can compare a fresh build with the
// committed one byte for byte.
import * as esbuild from "esbuild";
import { copyFileSync, mkdirSync } from "node:fs";

// The page speaks binary gRPC-Web only (useBinaryFormat in src/api.ts), so
// protobuf's JSON codec, which @connectrpc/connect's serialization imports
// for the JSON format, is never called: its modules are replaced by ones
// that say so if called (about 18 kB of the bundle).
const JSON_CODEC = {
  "./from-json.js": ["fromJson", "fromJsonString", "mergeFromJson", "mergeFromJsonString", "enumFromJson", "isEnumJson"],
  "./to-json.js": ["toJson", "toJsonString", "enumToJson"],
};
const binaryOnly = {
  name: "protobuf-binary-only",
  setup(build) {
    build.onResolve({ filter: /^\.\/(from|to)-json\.js$/ }, (args) =>
      /@bufbuild[\\/]protobuf[\\/]dist[\\/]esm[\\/]index\.js$/.test(args.importer)
        ? { path: args.path, namespace: "binary-only" }
        : undefined,
    );
    build.onLoad({ filter: /.*/, namespace: "binary-only" }, (args) => ({
      loader: "js",
      contents: [
        `const none = () => { throw new Error("protobuf JSON is not in the dashboard's bundle"); };`,
        ...JSON_CODEC[args.path].map((name) => `export const ${name} = none;`),
      ].join("\n"),
    }));
  },
};

mkdirSync("dist", { recursive: true });
await esbuild.build({
  entryPoints: { app: "src/main.ts" },
  plugins: [binaryOnly],
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
