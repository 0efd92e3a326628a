// Opens the rerun web viewer in headless Chromium and saves what a reviewer sees.
// Usage: node shoot.mjs URL OUT.png [SECONDS] [TAB]
import puppeteer from "puppeteer-core";

const [url, out, seconds = "60", tab = ""] = process.argv.slice(2);
const browser = await puppeteer.launch({
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  headless: true,
  args: [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
    "--window-size=1600,1000",
  ],
  defaultViewport: { width: 1600, height: 1000 },
});
const page = await browser.newPage();
page.on("console", (m) => {
  if (m.type() === "error") console.error(`viewer: ${m.text()}`);
});
await page.goto(url, { waitUntil: "load", timeout: 120_000 });
// The viewer is a WebAssembly app drawing into a canvas: give it time to load and decode.
await new Promise((r) => setTimeout(r, Number(seconds) * 1000));
if (tab) {
  // Tabs are drawn on the canvas: click where the tab's title is (x,y given as "x,y").
  const [x, y] = tab.split(",").map(Number);
  await page.mouse.click(x, y);
  await new Promise((r) => setTimeout(r, 10_000));
}
await page.screenshot({ path: out });
await browser.close();
console.log(`wrote ${out}`);
