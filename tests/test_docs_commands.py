"""The commands the documents show can be run as shown: every spec and example file they name ships
with jmlgdsl, and docs/fleet.md's live fleet, its first example, runs (on a mosquitto on 127.0.0.1
in place of the plant's broker) and gives every unit its run."""

import json
import re
import shlex
import subprocess

import pytest
from conftest import ROOT, jmlgdsl_command
from monitor_servers import MOSQUITTO, NO_MOSQUITTO, publish, query, stop, until

DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
NAMED = re.compile(r"\b(?:specs|examples)/[\w./-]*\w")  # a path into the repository's specs/ or examples/


def named_files():
    return sorted({(doc.name, path) for doc in DOCS for path in NAMED.findall(doc.read_text())})


@pytest.mark.parametrize("doc, path", named_files())
def test_every_file_a_document_names_ships(doc, path):
    assert (ROOT / path).exists(), f"{doc} names {path}, which does not ship"


def shown_commands(doc, heading):
    """The commands of the code blocks under a heading of a document, each line continuation joined."""
    text = (ROOT / "docs" / doc).read_text()
    section = text.split(f"\n## {heading}\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```\n(.*?)```", section, flags=re.S)
    return [shlex.split(line, comments=True) for block in blocks for line in block.replace("\\\n", " ").splitlines()
            if line.strip()]


@pytest.mark.skipif(MOSQUITTO is None, reason=NO_MOSQUITTO)
def test_the_live_fleet_example_runs(broker, tmp_path):
    pytest.importorskip("paho.mqtt.client")
    command = next(c for c in shown_commands("fleet.md", "A live fleet: the unit template") if c[1] == "monitor")
    port, store = broker(), str(tmp_path / "fleet.db")
    given = {"mqtt://broker.plant:1883/line4": f"mqtt://127.0.0.1:{port}/line4", "fleet.db": store}
    units = command[command.index("--units") + 1]
    assert units == "dryer01..dryer40"
    process = subprocess.Popen([*jmlgdsl_command(), *(given.get(word, word) for word in command[1:])], cwd=ROOT,
                               stderr=subprocess.PIPE, text=True)
    try:
        until(lambda: (query(store, "SELECT count(*) FROM event WHERE kind = 'connect'") or 0) >= 1,
              "the monitor to connect", process)
        publish(port, [("line4/dryer07", json.dumps({"t": t, "temp": 50.5, "current": 15})) for t in range(1, 6)])
        until(lambda: query(store, "SELECT count(*) FROM result JOIN run ON run.id = result.run "
                                   "WHERE run.unit = 'dryer07'") == 5, "dryer07's rows", process)
        stop(process)
    finally:
        process.kill()
    assert query(store, "SELECT count(DISTINCT unit) FROM run") == 40
