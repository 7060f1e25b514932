"""The CLI's record of what this machine has compiled, and the notice it prints before compiling."""

import json

import pytest

from ncjax.cli.compilation import FIRST_RUN_GUESS, LEDGER_FILE, CompileLedger, settings_key


def test_a_first_run_says_it_compiles_and_a_later_one_does_not(tmp_path):
    ledger = CompileLedger(str(tmp_path))
    first = ledger.notice("a", "the network")
    assert first == f"compiling the network (first run with these settings only; {FIRST_RUN_GUESS})"
    ledger.record("a", 95.04)
    again = CompileLedger(str(tmp_path))  # a new run reads what the last one wrote
    assert again.notice("a", "the network") is None
    assert again.notice("b", "the network").endswith("; about 95 s here)")
    assert json.loads((tmp_path / LEDGER_FILE).read_text()) == {"a": 95.0}
    again.record("b", 30.0)
    again.record("c", 41.0)
    assert again.notice("d", "the network").endswith("; about 41 s here)")  # the median, not the longest


def test_an_unreadable_or_unwritable_ledger_only_repeats_the_notice(tmp_path):
    (tmp_path / LEDGER_FILE).write_text("[1, 2")
    ledger = CompileLedger(str(tmp_path))
    assert ledger.notice("a", "x") is not None
    (tmp_path / LEDGER_FILE).write_text("[1, 2]")  # valid JSON, not a mapping
    assert CompileLedger(str(tmp_path)).seconds == {}
    blocked = tmp_path / "file"
    blocked.write_text("")
    CompileLedger(str(blocked / "cache")).record("a", 1.0)  # its folder cannot be made: nothing raised


def test_settings_keys_differ_with_the_settings():
    assert settings_key((1, 512, 1024, 3), "auto") == settings_key((1, 512, 1024, 3), "auto")
    assert settings_key((1, 512, 1024, 3), "auto") != settings_key((2, 512, 1024, 3), "auto")


def test_compiling_says_the_notice_once_and_records_only_calls_that_return(tmp_path):
    said = []
    ledger = CompileLedger(str(tmp_path))
    with pytest.raises(RuntimeError), ledger.compiling("k", "a program", said.append):
        raise RuntimeError("out of memory")
    assert len(said) == 1 and "k" not in ledger.seconds  # a failed call compiled nothing to remember
    with ledger.compiling("k", "a program", said.append):
        pass
    assert len(said) == 2 and "k" in CompileLedger(str(tmp_path)).seconds
    with ledger.compiling("k", "a program", said.append):
        pass
    assert len(said) == 2
