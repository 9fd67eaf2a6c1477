"""An embedded study's Ray listens on this machine only.

A real `prsm-sweep`-style run in a child process (a fresh interpreter, as the CLI is): while its
embedded Ray is up, every listening TCP socket of the driver, of Ray's processes (GCS, raylet,
agents) and of their workers is listed from the kernel's view (psutil). Without the loopback
setting GCS, raylet and workers listened on every interface (`::`) and the runtime-env agent on
the machine's external address; now every one must be on a loopback address.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

CHILD = textwrap.dedent("""
    import json, sys
    import psutil
    from pathlib import Path
    from prsm_ros.sweep import runner, study

    listening = []

    def sockets(tmp):
        me = psutil.Process()
        procs = {p.pid: p for p in me.children(recursive=True)}
        for p in psutil.process_iter(["cmdline"]):
            if tmp and tmp in " ".join(p.info["cmdline"] or []):
                procs[p.pid] = p
                procs.update({c.pid: c for c in p.children(recursive=True)})
        procs[me.pid] = me
        out = []
        for p in procs.values():
            try:
                out += [[c.laddr.ip, c.laddr.port, p.name()] for c in p.net_connections(kind="inet")
                        if c.status == psutil.CONN_LISTEN]
            except psutil.Error:
                pass
        return out

    real_disconnect = runner.disconnect

    def disconnect(ray, owned, tmp):  # list the sockets while the study's Ray is still up
        listening.extend(sockets(tmp))
        real_disconnect(ray, owned, tmp)

    runner.disconnect = disconnect
    norm = study.normalise({"preset": "s30", "model": "ideal", "scenario": "step", "duration_s": 0.01,
                            "metrics": ["efficiency"]})
    s = runner.run_study(norm, Path(sys.argv[1]), workers=1, progress=False)
    print("RESULT " + json.dumps({"listening": listening, "ran": s["ran"]}))
""")

LOOPBACK = ("127.", "::1", "::ffff:127.")


@pytest.mark.slow  # starts Ray in a child process
def test_an_embedded_study_listens_on_loopback_only(tmp_path):
    res = subprocess.run([sys.executable, "-c", CHILD, str(tmp_path / "out")], capture_output=True, text=True,
                         timeout=300, cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert res.returncode == 0, res.stderr[-3000:]
    r = json.loads(res.stdout.split("RESULT ", 1)[1])
    assert r["ran"] == 1
    names = {name for _, _, name in r["listening"]}
    assert {"gcs_server", "raylet"} <= names, r["listening"]  # the listing saw Ray's own servers
    exposed = [s for s in r["listening"] if not s[0].startswith(LOOPBACK)]
    assert exposed == [], f"listening beyond loopback: {exposed}"
