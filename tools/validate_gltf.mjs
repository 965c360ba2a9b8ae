#!/usr/bin/env node
// Validate a .glb/.gltf file with the Khronos glTF validator and print the report.
//
// Usage: node tools/validate_gltf.mjs FILE.glb
//
// The validator package (npm "gltf-validator") is looked up in $GLTF_VALIDATOR_DIR,
// else in .tools/node/node_modules/gltf-validator at the repository root
// (install it with `npm install --prefix .tools/node gltf-validator`).
// Prints the validation report as JSON on stdout and exits 0 whatever the report
// says; exits 2 on a usage error, an unreadable file or a missing validator.
import { readFileSync } from "node:fs";
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const validatorDir =
  process.env.GLTF_VALIDATOR_DIR ||
  path.join(here, "..", ".tools", "node", "node_modules", "gltf-validator");

const file = process.argv[2];
if (!file || process.argv.length > 3) {
  console.error("usage: node tools/validate_gltf.mjs FILE.glb");
  process.exit(2);
}

let validator;
try {
  validator = createRequire(import.meta.url)(path.resolve(validatorDir));
} catch (err) {
  console.error(`cannot load gltf-validator from ${validatorDir}: ${err}`);
  process.exit(2);
}

let data;
try {
  data = new Uint8Array(readFileSync(file));
} catch (err) {
  console.error(`cannot read ${file}: ${err}`);
  process.exit(2);
}

try {
  const report = await validator.validateBytes(data, {
    uri: path.basename(file),
    maxIssues: 0,
    writeTimestamp: false,
  });
  process.stdout.write(JSON.stringify(report, null, 2) + "\n");
  process.exit(0);
} catch (err) {
  // The validator rejects only when it cannot even detect the format.
  console.error(`gltf-validator could not validate ${file}: ${err}`);
  process.exit(2);
}
