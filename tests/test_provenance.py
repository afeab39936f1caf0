"""Provenance: regenerated results do not mark the code dirty; code changes do."""

import subprocess

import pytest

import experiments.provenance as prov


def _git(repo, *args):
    subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True)


@pytest.fixture
def repo(tmp_path, monkeypatch):
    for d in ("estimator", "results"):
        (tmp_path / d).mkdir()
    (tmp_path / "estimator" / "a.py").write_text("x = 1\n")
    (tmp_path / "results" / "tables.md").write_text("old\n")
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "init")
    monkeypatch.setattr(prov, "REPO", tmp_path)
    return tmp_path


def test_results_changes_are_not_dirty_code_changes_are(repo):
    clean = prov.git_describe()
    assert clean and not clean.endswith("-dirty") and not clean.startswith("unknown")
    (repo / "results" / "tables.md").write_text("regenerated\n")
    assert prov.git_describe() == clean
    (repo / "estimator" / "a.py").write_text("x = 2\n")
    assert prov.git_describe() == clean + "-dirty"
    info = prov.code_version()
    assert info["git_describe"] == clean + "-dirty" and len(info["git_commit"]) == 40


def test_outside_a_checkout(tmp_path, monkeypatch):
    monkeypatch.setattr(prov, "REPO", tmp_path)
    assert prov.git_describe() == "unknown (not a git checkout)"
    assert prov.code_version()["git_describe"] is None


def test_a_commit_of_results_keeps_the_code_version(repo):
    """Regenerated references are committed after the code that made them: a rerun at the
    results commit must write the same provenance (the newest commit that changed code)."""
    before = prov.code_version()
    (repo / "results" / "tables.md").write_text("regenerated\n")
    _git(repo, "add", ".")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "results")
    after = prov.code_version()
    assert after["git_describe"] == before["git_describe"]
    assert after["git_commit"] == before["git_commit"]
    (repo / "estimator" / "a.py").write_text("x = 3\n")
    _git(repo, "add", ".")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "code")
    assert prov.code_version()["git_commit"] != before["git_commit"]
