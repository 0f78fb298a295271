"""Long jobs' progress bars reach a log file, not only a terminal."""

import io
import time

from drem_maniskill.utils import progress


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_bar_writing_to_a_file_shows_its_progress():
    log = io.StringIO()  # what `nohup job > log 2>&1` gives a bar: not a terminal
    for _ in progress.progress_bar(range(3), desc="examine: expert", file=log):
        pass
    assert "examine: expert" in log.getvalue() and "3/3" in log.getvalue()


def test_off_a_terminal_a_bar_refreshes_at_the_log_interval_and_on_a_terminal_at_tqdms_own(monkeypatch):
    monkeypatch.setattr(progress, "LOG_INTERVAL_S", 60.0)
    log, tty = io.StringIO(), _Terminal()
    for stream in (log, tty):
        bar = progress.progress_bar(total=1000, file=stream)
        for _ in range(1000):
            bar.update(1)
            time.sleep(0.0002)  # 0.2 s in all: tqdm's 0.1 s refresh fires on a terminal, the 60 s one does not
        bar.close()
    # A log file gets the bar's first and last state; a terminal gets the updates in between too.
    assert log.getvalue().count("\r") <= 3
    assert tty.getvalue().count("\r") > log.getvalue().count("\r")


def test_a_disabled_bar_writes_nothing():
    log = io.StringIO()
    for _ in progress.progress_bar(range(3), enabled=False, file=log):
        pass
    assert log.getvalue() == ""
