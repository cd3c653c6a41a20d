// Opens a splat file in Spark (three.js) in headless Chromium and saves a screenshot.
// The page, three.js and Spark are served from this machine (no CDN); WebGL runs on
// SwiftShader, Chromium's software renderer.
//
// node spark-screenshot.mjs TOOLS_DIR SPLAT_FILE OUT_PNG WIDTH HEIGHT FOV_DEG EX EY EZ TX TY TZ
//
// The camera looks from E at T with world −y up (our frame is OpenCV's, +y down), so the
// picture matches `metasplat render --camera EX,EY,EZ,TX,TY,TZ --fov FOV_DEG` of the file.
import fs from "node:fs";
import http from "node:http";
import path from "node:path";
import { createRequire } from "node:module";

const [tools, splatFile, outPng, w, h, fov, ...pose] = process.argv.slice(2);
if (pose.length !== 6) {
  console.error("usage: spark-screenshot.mjs TOOLS SPLAT OUT W H FOV EX EY EZ TX TY TZ");
  process.exit(2);
}
const require = createRequire(path.join(tools, "node_modules", "x.js"));
const { chromium } = require("playwright-core");
const modules = path.join(tools, "node_modules");
const ext = path.extname(splatFile).toLowerCase();

const page = `<!doctype html><html><head><style>body{margin:0;background:#000}</style>
<script type="importmap">{"imports":{"three":"/three/three.module.js","three/addons/":"/three-addons/","@sparkjsdev/spark":"/spark/spark.module.js"}}</script>
</head><body><script type="module">
import * as THREE from "three";
import { SparkRenderer, SplatMesh } from "@sparkjsdev/spark";
try {
  const [w, h, fov] = [${Number(w)}, ${Number(h)}, ${Number(fov)}];
  const pose = ${JSON.stringify(pose.map(Number))};
  const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(w, h);
  document.body.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0, 0, 0);
  const camera = new THREE.PerspectiveCamera(fov, w / h, 0.01, 1000);
  camera.up.set(0, -1, 0);
  camera.position.set(pose[0], pose[1], pose[2]);
  camera.lookAt(pose[3], pose[4], pose[5]);
  scene.add(new SparkRenderer({ renderer }));
  const mesh = new SplatMesh({ url: "/scene${ext}" });
  scene.add(mesh);
  await mesh.initialized;
  window.__splats = mesh.packedSplats ? mesh.packedSplats.numSplats : -1;
  console.log("loaded " + window.__splats + " splats");
  let frames = 0;
  renderer.setAnimationLoop(() => {
    renderer.render(scene, camera);
    frames += 1;
    // Spark sorts in a worker: give it frames to settle before the picture.
    if (frames % 10 === 0) console.log("frame " + frames);
    if (frames === 12) window.__ready = true;
  });
} catch (e) {
  window.__error = String(e && e.stack || e);
}
</script></body></html>`;

const files = {
  "/": ["text/html", () => page],
  [`/scene${ext}`]: ["application/octet-stream", () => fs.readFileSync(splatFile)],
};
const server = http.createServer((req, res) => {
  const url = req.url.split("?")[0];
  let body, type;
  if (files[url]) {
    [type, body] = [files[url][0], files[url][1]()];
  } else {
    const roots = {
      "/three/": "three/build/",
      "/three-addons/": "three/examples/jsm/",
      "/spark/": "@sparkjsdev/spark/dist/",
    };
    const root = Object.keys(roots).find((r) => url.startsWith(r));
    const file = root && path.join(modules, roots[root], path.normalize(url.slice(root.length)));
    if (!file || !file.startsWith(modules) || !fs.existsSync(file)) {
      if (url !== "/favicon.ico") messages.push(`not served: ${url}`);
      res.writeHead(404);
      res.end();
      return;
    }
    [type, body] = [file.endsWith(".wasm") ? "application/wasm" : "text/javascript", fs.readFileSync(file)];
  }
  res.writeHead(200, { "content-type": type });
  res.end(body);
});
await new Promise((ok) => server.listen(0, "127.0.0.1", ok));
const port = server.address().port;

const browser = await chromium.launch({
  executablePath: process.env.METASPLAT_CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: [
    "--no-sandbox",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-default-apps",
    "--no-first-run",
  ],
});
let status = 0;
const messages = [];
try {
  const tab = await browser.newPage({ viewport: { width: Number(w), height: Number(h) } });
  tab.on("console", (m) => messages.push(m.text()));
  tab.on("pageerror", (e) => messages.push(String(e)));
  await tab.goto(`http://127.0.0.1:${port}/`);
  await tab.waitForFunction(() => window.__ready || window.__error, null, { timeout: Number(process.env.METASPLAT_SPARK_TIMEOUT_MS || 120000) });
  const error = await tab.evaluate(() => window.__error);
  if (error) {
    console.error(`Spark failed: ${error}\n${messages.join("\n")}`);
    status = 1;
  } else {
    const splats = await tab.evaluate(() => window.__splats);
    await tab.locator("canvas").screenshot({ path: outPng });
    console.log(`splats ${splats}`);
  }
} catch (e) {
  console.error(`the browser check failed: ${e}\n${messages.join("\n")}`);
  status = 1;
} finally {
  await browser.close();
  server.close();
}
process.exit(status);
