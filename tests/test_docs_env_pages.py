"""The env pages of the documentation site (``docs/envs/``) are what ``docs/gen_env_pages.py``
writes from the package now: a change of a space, a step limit, an id or a scenario's numbers
needs ``python docs/gen_env_pages.py`` (and the pages committed with it)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "docs" / "gen_env_pages.py"


def test_env_pages_are_up_to_date(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    spec = importlib.util.spec_from_file_location("gen_env_pages", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # its dataclasses look it up there
    spec.loader.exec_module(module)
    status = module.main(["--check"])
    assert status == 0, capsys.readouterr().err
