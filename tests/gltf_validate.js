// Validate a glTF file with the Khronos glTF validator (npm's gltf-validator), for tests/test_export.py.
//
//   node tests/gltf_validate.js VALIDATOR_PACKAGE_DIR FILE.gltf
//
// prints the validator's report as JSON (issues, info on the resources it loaded). External
// resources (buffers, images) are read relative to FILE's folder, so they are validated too.
"use strict";
const fs = require("fs");
const path = require("path");

const [packageDir, file] = process.argv.slice(2);
if (!packageDir || !file) {
  console.error("usage: node gltf_validate.js VALIDATOR_PACKAGE_DIR FILE.gltf");
  process.exit(2);
}
const validator = require(path.resolve(packageDir));
const folder = path.dirname(path.resolve(file));
validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
  uri: path.basename(file),
  maxIssues: 0,  // all of them
  externalResourceFunction: (uri) => new Promise((resolve, reject) => {
    fs.readFile(path.resolve(folder, decodeURIComponent(uri)), (err, data) => err ? reject(err.toString()) : resolve(data));
  }),
}).then(
  (report) => console.log(JSON.stringify(report, null, 1)),
  (error) => { console.error(String(error)); process.exit(1); });
