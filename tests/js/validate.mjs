// The Khronos glTF-Validator on one file: prints its report (JSON) for tests/test_export.py.
import fs from 'fs';
import validator from 'gltf-validator';

const data = new Uint8Array(fs.readFileSync(process.argv[2]));
const report = await validator.validateBytes(data, {maxIssues: 100});
console.log(JSON.stringify(report));
