// Validates GLB files with the Khronos glTF validator; prints one JSON report summary per file.
// Usage: node validate.js FILE.glb [FILE.glb ...]
const fs = require("fs");
const validator = require("gltf-validator");

async function main() {
  for (const path of process.argv.slice(2)) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(path)));
    const messages = report.issues.messages.map((m) => `${m.code}: ${m.message} (${m.pointer || ""})`);
    console.log(JSON.stringify({
      path, errors: report.issues.numErrors, warnings: report.issues.numWarnings,
      infos: report.issues.numInfos, hints: report.issues.numHints, messages,
    }));
  }
}
main().catch((e) => { console.error(String(e)); process.exit(1); });
