// Run a MicroPython script on the webassembly port, whose small ints are 31-bit
// as on the RP2040 and the ESP32 (sys.maxsize = 2^31 - 1): an int >= 2^30 is a
// heap object there, so under micropython.heap_lock() it is a MemoryError, as in a
// board's hard interrupt. The unix port on PyPI is 64-bit and cannot show that.
//
// usage: node run.mjs [--heap MB] DIR[:DIR...] SCRIPT [ARGS...]
// Every .py file of each DIR is copied into the port's in-memory file system, the
// DIRs go on sys.path in that order, sys.argv is [SCRIPT, ARGS...]; an ARG that names
// an existing file is copied to /data/ and its argument becomes that path. Exit status:
// the script's SystemExit code, 1 on an uncaught exception (printed on stderr).
//
// The port has no native code emitter, so a `@micropython.viper` function cannot be
// compiled. codec.py's are run as plain bytecode (the decorator dropped: their type
// annotations are then ignored) -- the same source as on a board -- except
// crc32_store, whose uint CRC is >= 2^30 and so a heap object in Python: it is
// replaced by the rendering in viper_free.py, which keeps the CRC in 16-bit halves.
// On a board viper works in machine words and makes no Python int, so the 31-bit
// question does not arise inside these functions; heap_lock() still holds here.
import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";
import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";

const HERE = path.dirname(fileURLToPath(import.meta.url));
const RENDERED = ["crc32_store"]; // viper functions replaced by viper_free.py's

function withoutViper(src, file) {
  const lines = src.split("\n");
  const out = [];
  const rendered = [];
  for (let i = 0; i < lines.length; i++) {
    if (!lines[i].startsWith("@micropython.viper")) {
      out.push(lines[i]);
      continue;
    }
    const m = /^def (\w+)/.exec(lines[i + 1] || "");
    if (!m) throw new Error(`${file}: @micropython.viper not followed by a def`);
    if (!RENDERED.includes(m[1])) continue; // the decorator goes, the function stays
    rendered.push(m[1]);
    i += 2;
    while (i < lines.length && (lines[i] === "" || /^\s/.test(lines[i]))) i++;
    i--;
    out.push(`from viper_free import ${m[1]}`, "");
  }
  if (file === "codec.py" && rendered.join() !== RENDERED.join()) {
    throw new Error(`codec.py: expected viper ${RENDERED} to render, found ${rendered}`);
  }
  return out.join("\n");
}

async function main() {
  const argv = process.argv.slice(2);
  let heapMb = 16;
  if (argv[0] === "--heap") {
    heapMb = Number(argv[1]);
    argv.splice(0, 2);
  }
  if (argv.length < 2) {
    process.stderr.write("usage: node run.mjs [--heap MB] DIR[:DIR...] SCRIPT [ARGS...]\n");
    process.exit(2);
  }
  const dirs = [...argv[0].split(":").filter(Boolean), HERE];
  const script = argv[1];
  const args = argv.slice(2);
  const mp = await loadMicroPython({
    heapsize: heapMb * 1024 * 1024,
    pystack: 64 * 1024,
    stdout: (line) => process.stdout.write(line + "\n"),
    stderr: (line) => process.stderr.write(line + "\n"),
  });
  const sysPath = [];
  dirs.forEach((dir, k) => {
    const dest = `/p${k}`;
    mp.FS.mkdir(dest);
    for (const name of fs.readdirSync(dir)) {
      if (!name.endsWith(".py")) continue;
      let src = fs.readFileSync(path.join(dir, name), "utf8");
      if (src.includes("@micropython.viper")) src = withoutViper(src, name);
      mp.FS.writeFile(`${dest}/${name}`, src);
    }
    sysPath.push(dest);
  });
  mp.FS.mkdir("/data");
  const pyArgs = args.map((a) => {
    if (!fs.existsSync(a) || !fs.statSync(a).isFile()) return a;
    const dest = `/data/${path.basename(a)}`;
    mp.FS.writeFile(dest, fs.readFileSync(a));
    return dest;
  });
  const code = fs.readFileSync(script, "utf8");
  mp.globals.set("_mp31_path", sysPath.join(":"));
  mp.globals.set("_mp31_argv", [script, ...pyArgs].join("\u0001"));
  try {
    mp.runPython(
      "import sys\n" +
        "sys.path[:0] = _mp31_path.split(':')\n" +
        "sys.argv[:] = _mp31_argv.split('\\x01')\n" +
        "del _mp31_path, _mp31_argv\n",
    );
    mp.runPython(code);
  } catch (e) {
    if (e.name !== "PythonError") throw e;
    if (e.type === "SystemExit") {
      const m = /SystemExit: (\d+)/.exec(e.message);
      process.exitCode = m ? Number(m[1]) : 0;
      return;
    }
    process.stderr.write(e.message);
    process.exitCode = 1;
  }
}

main();
