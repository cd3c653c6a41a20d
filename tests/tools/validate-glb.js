// Validates a GLB or .gltf with Khronos' glTF-Validator; the extension's own attribute names are
// reported as MESH_PRIMITIVE_INVALID_ATTRIBUTE (the validator does not know the extension
// yet), so that one code is informational. Prints the report; exits 1 on any error.
const fs = require('fs');
const validator = require('gltf-validator');
const bytes = new Uint8Array(fs.readFileSync(process.argv[2]));
validator.validateBytes(bytes, {
  severityOverrides: { MESH_PRIMITIVE_INVALID_ATTRIBUTE: 2 },
  maxIssues: 100,
}).then((report) => {
  const i = report.issues;
  console.log(JSON.stringify({ errors: i.numErrors, warnings: i.numWarnings, infos: i.numInfos,
    messages: i.messages.filter((m) => m.severity <= 1).slice(0, 20) }));
  process.exit(i.numErrors > 0 ? 1 : 0);
}).catch((e) => { console.error(String(e)); process.exit(2); });
