"""The progress bar: a no-op when disabled (but print still prints), and when enabled the label, the
count and the info text reach the console."""

from __future__ import annotations

import io

from rich.console import Console

from bimgame.util.progress import ProgressBar, escape


def _console() -> tuple[Console, io.StringIO]:
    buffer = io.StringIO()
    return Console(file=buffer, force_terminal=False, width=120, color_system=None), buffer


def test_disabled_bar_draws_nothing_but_print_still_prints():
    console, buffer = _console()
    with ProgressBar("Training", 10, enabled=False, console=console, info="start info") as bar:
        bar.update(advance=3, info="ignored info", label="ignored label")
        bar.update(completed=10)
        bar.print("a [bold]plain[/bold] line")
    assert buffer.getvalue() == "a plain line\n"
    bar.print("after the block")
    assert buffer.getvalue().endswith("after the block\n")


def test_update_before_enter_and_after_exit_is_a_no_op():
    console, buffer = _console()
    bar = ProgressBar("Idle", 5, console=console)
    bar.update(advance=1, info="x")  # not entered yet: nothing to update
    assert buffer.getvalue() == ""
    with bar:
        bar.update(completed=5, info="finished")
    written = buffer.getvalue()
    bar.update(advance=1, info="late")  # exited: no-op, nothing more written
    assert buffer.getvalue() == written
    assert "late" not in written


def test_enabled_bar_shows_label_count_and_info():
    console, buffer = _console()
    with ProgressBar("Training", 10, console=console, info="start") as bar:
        bar.update(advance=3, info="acc 0.75")
        bar.update(advance=4, info="success 70%")
        bar.print(escape("[a message]"))
    text = buffer.getvalue()
    assert "[a message]" in text
    assert "Training" in text
    assert "7/10" in text
    assert "success 70%" in text
    assert "start" not in text  # the info text was replaced


def test_label_can_be_replaced():
    console, buffer = _console()
    with ProgressBar("First", 4, console=console) as bar:
        bar.update(completed=4, label="Second")
    text = buffer.getvalue()
    assert "Second" in text and "First" not in text and "4/4" in text


def test_count_format_string_shows_done_and_total():
    console, buffer = _console()
    with ProgressBar("Steps", 2000, console=console, count="{done:,.0f}/{total:,.0f} steps", completed=100) as bar:
        bar.update(advance=1400)
    assert "1,500/2,000 steps" in buffer.getvalue()


def test_no_count_and_eta_columns():
    console, buffer = _console()
    with ProgressBar("Quiet", 10, console=console, count=None, eta=True) as bar:
        bar.update(completed=3, info="three done")
    text = buffer.getvalue()
    assert "3/10" not in text
    assert "three done" in text and "ETA" in text


def test_transient_bar_leaves_no_output():
    console, buffer = _console()
    with ProgressBar("Gone", 3, console=console, transient=True) as bar:
        bar.update(completed=3, info="whatever")
    assert "Gone" not in buffer.getvalue()


def test_default_console_is_stderr():
    assert ProgressBar("x", 1).console.stderr is True
