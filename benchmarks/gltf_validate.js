// The Khronos glTF validator on one file: node benchmarks/gltf_validate.js FILE.glb (npm install gltf-validator;
// NODE_PATH=<that node_modules> when installed elsewhere). Prints counts of errors, warnings, infos, hints and the codes.
const fs = require('fs');
const validator = require('gltf-validator');
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator.validateBytes(data).then((r) => {
  const codes = {};
  for (const m of r.issues.messages) codes[m.code + ' (severity ' + m.severity + ')'] = (codes[m.code + ' (severity ' + m.severity + ')'] || 0) + 1;
  console.log(JSON.stringify({validatorVersion: r.validatorVersion, numErrors: r.issues.numErrors, numWarnings: r.issues.numWarnings,
    numInfos: r.issues.numInfos, numHints: r.issues.numHints, codes: codes, info: r.info}, null, 1));
}).catch((e) => { console.error(e); process.exit(1); });
