"""Run command lines of ``particlesplat`` and ``particlesplat-viewer`` each in its own process under a memory cap.

Used by the hostile-input suite: ``python runner.py CASES.json RESULTS.json``. The parent imports the commands
once; each case runs in a forked child (a separate process, so a blow-up or a crash stays in it) whose address
space may grow by at most ``cap_mb`` over the parent's (``resource.setrlimit(RLIMIT_AS)``), optionally with a
file-size limit (``fsize``: a full disk as far as the command can tell). A result is the exit code, the
output (stdout, stderr), the wall time and the child's peak resident memory.

CASES.json: a list of {"entry": "particlesplat" | "particlesplat-viewer" | "alloc" (argv: [MB]) | "call" (argv:
["module:function", arguments...], a function of a module beside this file, returning the exit code),
"argv": [...], "cap_mb": int,
"fsize": int | null, "env": {variable: value} | null, "timeout": seconds, "watch": [folders]}; a result also lists
the files under ``watch`` that were added, removed or changed ("changed").
"""

from __future__ import annotations

import hashlib
import json
import os
import resource
import select
import signal
import sys
import time


def _vm_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmSize in /proc/self/status")


def _child(case: dict, out_fd: int, err_fd: int) -> None:
    os.dup2(out_fd, 1)
    os.dup2(err_fd, 2)
    cap = _vm_bytes() + case["cap_mb"] * (1 << 20)
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    if case.get("fsize"):
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (case["fsize"], case["fsize"]))
    os.environ.update(case.get("env") or {})
    code = 99
    try:
        if case["entry"] == "alloc":  # the cap's own check: allocate argv[0] MB
            bytearray(int(case["argv"][0]) << 20)
            code = 0
        elif case["entry"] == "call":
            import importlib

            module, _, name = case["argv"][0].partition(":")
            code = getattr(importlib.import_module(module), name)(*case["argv"][1:])
        elif case["entry"] == "particlesplat":
            from particlesplat.cli.main import console_main

            sys.argv = ["particlesplat", *case["argv"]]
            code = console_main()
        else:
            from viewer.launch import main

            sys.argv = ["particlesplat-viewer", *case["argv"]]
            code = main(case["argv"])
    except BaseException:  # noqa: BLE001 - a traceback is a finding: report it
        import traceback

        traceback.print_exc()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(int(code or 0) & 0xFF)


def _snapshot(folders: list[str]) -> dict[str, str]:
    """path -> digest of every file (and link, FIFO, device: by its kind) under ``folders``."""
    out = {}
    for folder in folders:
        for root, dirs, files in os.walk(folder):
            for name in files + [d for d in dirs if os.path.islink(os.path.join(root, d))]:
                p = os.path.join(root, name)
                st = os.lstat(p)
                if os.path.islink(p):
                    out[p] = "link:" + os.readlink(p)
                elif not os.path.isfile(p):
                    out[p] = f"special:{st.st_mode}"
                else:
                    with open(p, "rb") as f:
                        out[p] = hashlib.sha256(f.read()).hexdigest()
            out.update({os.path.join(root, d) + "/": "dir" for d in dirs})
    return out


def run_case(case: dict) -> dict:
    before = _snapshot(case.get("watch", []))
    (r_out, w_out), (r_err, w_err) = os.pipe(), os.pipe()
    t0 = time.perf_counter()
    pid = os.fork()
    if pid == 0:
        os.close(r_out)
        os.close(r_err)
        _child(case, w_out, w_err)
    os.close(w_out)
    os.close(w_err)
    got = {r_out: bytearray(), r_err: bytearray()}
    open_fds = [r_out, r_err]
    deadline = t0 + case.get("timeout", 60)
    killed = False
    while open_fds:
        left = deadline - time.perf_counter()
        if left <= 0:
            os.kill(pid, signal.SIGKILL)
            killed = True
            break
        ready, _, _ = select.select(open_fds, [], [], left)
        for fd in ready:
            chunk = os.read(fd, 1 << 16)
            if not chunk:
                open_fds.remove(fd)
            elif len(got[fd]) < (1 << 20):  # a runaway message is kept only in part
                got[fd] += chunk
    os.close(r_out)
    os.close(r_err)
    _, status, usage = os.wait4(pid, 0)
    code = os.waitstatus_to_exitcode(status)
    seconds = time.perf_counter() - t0
    after = _snapshot(case.get("watch", []))
    changed = sorted(p for p in set(before) | set(after) if before.get(p) != after.get(p))
    return {
        "code": code,
        "stdout": got[r_out].decode("utf-8", "replace"),
        "stderr": got[r_err].decode("utf-8", "replace"),
        "seconds": seconds,
        "max_rss_mb": usage.ru_maxrss / 1024.0,
        "timed_out": killed,
        "changed": changed,
    }


def main() -> None:
    cases = json.loads(open(sys.argv[1]).read())
    import torch  # noqa: F401 - imported once here, shared by every forked case

    import particlesplat.analysis.evaluate  # noqa: F401
    import particlesplat.cli.main  # noqa: F401
    import particlesplat.cli.render  # noqa: F401
    import particlesplat.training.trainer  # noqa: F401
    import viewer.app  # noqa: F401

    torch.set_num_threads(1)
    results = [run_case(c) for c in cases]
    with open(sys.argv[2], "w") as f:
        json.dump(results, f)


if __name__ == "__main__":
    main()
