// Opens the rerun web viewer in headless Chromium and saves what a reviewer sees: the opening
// view (part.png), then the layer history tab (history.png); with REPORT, the report's page
// too (report.png, the whole page).
// Usage: node shoot.mjs URL OUT_DIR [SECONDS] [TAB_X,TAB_Y] [REPORT.html]
import puppeteer from "puppeteer-core";

const [url, out, seconds = "60", tab = "119,40", report] = process.argv.slice(2);
const wait = (s) => new Promise((r) => setTimeout(r, s * 1000));
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
await wait(Number(seconds));
await page.screenshot({ path: `${out}/part.png` });
console.log(`wrote ${out}/part.png`);
// Tabs are drawn on the canvas: click where the second tab's title is.
const [x, y] = tab.split(",").map(Number);
await page.mouse.click(x, y);
await wait(15);
await page.screenshot({ path: `${out}/history.png` });
console.log(`wrote ${out}/history.png`);
if (report) {
  const doc = await browser.newPage();
  await doc.goto(`file://${report}`, { waitUntil: "load", timeout: 60_000 });
  await doc.screenshot({ path: `${out}/report.png`, fullPage: true });
  console.log(`wrote ${out}/report.png`);
}
await browser.close();
