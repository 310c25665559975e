// Builds the studio into dist/: one minified ES module (the studio's
// sources and the parts of three.js they import), its style, and the page,
// which names the build by a hash of the script so browsers never mix an
// old script with a new page. dist/ is committed; `cargo build` embeds it
// and needs no Node. Run: npm ci && npm run build (in web/).
import { build } from "esbuild";
import { createHash } from "node:crypto";
import { mkdirSync, readFileSync, writeFileSync } from "node:fs";

const here = new URL(".", import.meta.url).pathname;
mkdirSync(`${here}dist`, { recursive: true });
await build({
  entryPoints: [`${here}src/main.js`],
  bundle: true,
  minify: true,
  format: "esm",
  target: "es2020",
  legalComments: "eof",
  outfile: `${here}dist/studio.js`,
});
const js = readFileSync(`${here}dist/studio.js`);
const css = readFileSync(`${here}src/studio.css`);
writeFileSync(`${here}dist/studio.css`, css);
const tag = createHash("sha256").update(js).update(css).digest("hex").slice(0, 12);
const html = readFileSync(`${here}src/index.html`, "utf8").replaceAll("__BUILD__", tag);
writeFileSync(`${here}dist/index.html`, html);
console.log(`studio built: studio.js ${js.length} bytes, build ${tag}`);
