"""The command line: ``simnav mission --viz --html`` end to end, then ``simnav view`` on its run folder."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
from urllib.parse import urlparse

import pytest
from typer.testing import CliRunner

import simnav.cli.view  # noqa: F401  (registers `simnav view` on the app)
from simnav.cli.app import app
from simnav.viz import RECORDING_FILE

runner = CliRunner()
CLI = ["-c", "import simnav.cli.view; from simnav.cli import main; main()"]
URL = re.compile(r"meshcat: (http://127\.0\.0\.1:\d+/static/)")


def port_open(url: str) -> bool:
    parsed = urlparse(url)
    with socket.socket() as s:
        s.settimeout(1.0)
        return s.connect_ex((parsed.hostname, parsed.port)) == 0


@pytest.fixture(scope="module")
def mission_run(tmp_path_factory):
    """``simnav mission --viz --html`` in a subprocess: 2 s in the flat world with one person."""
    tmp = tmp_path_factory.mktemp("cli")
    out, html = tmp / "run", tmp / "replay.html"
    result = subprocess.run([sys.executable, *CLI, "mission", "--world", "flat", "--agents", "1", "--robots", "0",
                             "--duration", "2", "--viz", "--html", str(html), "--out", str(out)],
                            capture_output=True, text=True, timeout=300)
    return result, out, html


@pytest.mark.slow
def test_mission_viz_prints_the_url_writes_the_replay_and_stops_the_server(mission_run):
    result, out, html = mission_run
    assert result.returncode == 0, result.stderr
    url = URL.search(result.stderr)
    assert url, result.stderr
    assert not port_open(url.group(1))  # the server went down with the command
    assert f"replay: {html}" in " ".join(result.stdout.split())
    assert html.stat().st_size > 500_000 and "MeshCat.Viewer" in html.read_text()
    assert (out / RECORDING_FILE).is_file() and (out / "report.json").is_file()
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_view_replays_a_run_as_html_and_on_a_server(mission_run, tmp_path):
    _, out, _ = mission_run
    html = tmp_path / "again.html"
    result = runner.invoke(app, ["view", str(out), "--html", str(html)])
    assert result.exit_code == 0, result.output
    assert html.is_file() and "MeshCat.Viewer" in html.read_text()
    served = runner.invoke(app, ["view", str(out), "--exit-after", "0.5"])
    assert served.exit_code == 0, served.output
    url = URL.search(served.stderr)
    assert url, served.stderr
    assert not port_open(url.group(1))


def test_view_on_a_folder_without_a_recording_is_one_red_line(tmp_path):
    result = runner.invoke(app, ["view", str(tmp_path)])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(tmp_path) in lines[0] and RECORDING_FILE in lines[0]
    assert "Traceback" not in result.output
