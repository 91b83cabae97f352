// Validates a .glb or .gltf with the Khronos glTF validator (npm `gltf-validator`) and prints
// one JSON line: the issue counts and every message. Exit 0 without errors, 1 with, 2 if the
// validator could not run.
//
//   NODE_PATH=<folder holding node_modules> node tests/gltf/validate.js FILE
const fs = require('fs');
const path = require('path');
const validator = require('gltf-validator');

const file = path.resolve(process.argv[2]);
const dir = path.dirname(file);
validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
  uri: path.basename(file),
  maxIssues: 0,
  writeTimestamp: false,
  // External buffers and images are read from beside the file.
  externalResourceFunction: (uri) => new Promise((resolve, reject) =>
    fs.readFile(path.resolve(dir, decodeURIComponent(uri)),
      (err, data) => (err ? reject(err.toString()) : resolve(new Uint8Array(data))))),
}).then((report) => {
  const i = report.issues;
  console.log(JSON.stringify({
    file, validator: report.validatorVersion,
    errors: i.numErrors, warnings: i.numWarnings, infos: i.numInfos, hints: i.numHints,
    messages: i.messages.map((m) => ({ code: m.code, severity: m.severity, pointer: m.pointer, message: m.message })),
  }));
  process.exit(i.numErrors > 0 ? 1 : 0);
}, (err) => {
  console.error(`${file}: the validator failed: ${err}`);
  process.exit(2);
});
