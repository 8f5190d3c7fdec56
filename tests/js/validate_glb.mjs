// The Khronos glTF-Validator on a file: node validate_glb.mjs FILE.glb -> its report (JSON) on stdout
import fs from 'node:fs';
import validator from 'gltf-validator';

const file = process.argv[2];
const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), { maxIssues: 100 });
process.stdout.write(JSON.stringify(report));
