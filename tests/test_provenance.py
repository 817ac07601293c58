"""experiments/_provenance.py: the record that goes with every dated result."""

from __future__ import annotations

import subprocess


def test_a_run_from_changed_files_says_so(experiment_script, tmp_path):
    prov = experiment_script("_provenance")
    assert prov.git_revision(tmp_path) == "unknown"  # not a repository
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    subprocess.run([*git, "init", "-q"], check=True)
    (tmp_path / "a.py").write_text("x = 1\n")
    subprocess.run([*git, "add", "a.py"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "a"], check=True)
    clean = prov.git_revision(tmp_path)
    assert len(clean) >= 7 and "+" not in clean
    (tmp_path / "a.py").write_text("x = 2\n")
    assert prov.git_revision(tmp_path) == clean + "+changes"
