"""In-process CLI runner shared by the CLI tests."""

import json

from jaxsss.cli import main


def run_cli(capsys, *argv):
    """Run ``jaxsss *argv`` in-process; return ``(exit code, stdout, stderr)``."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def run_json(capsys, *argv):
    """Run with ``--json``; assert success and a clean stderr; return the parsed object."""
    code, out, err = run_cli(capsys, *argv, "--json")
    assert code == 0, err
    assert err == ""
    return json.loads(out)
