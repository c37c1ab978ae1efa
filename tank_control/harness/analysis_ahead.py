"""A ROS run's loop analysis computed while the run goes on, not after it.

``metrics.json``'s ``loop_analysis`` and ``analysis.png`` depend on the scenario and on the
controller's parameters only, not on the trace. A ROS run asks the controller for its
parameters once its graph is up and, in a thread, imports what writes the results
(matplotlib: about a second), builds the loop cases, their reports and ``analysis.png`` (to a
file beside it) while the loop runs. At the end they are used only if the controller's final
parameters equal those (an auto-tuner or a live change makes them differ: then everything is
computed again from the final ones, as an in-process run does). Nothing of it is shared with
the main thread before :meth:`AnalysisAhead.take` has joined the thread (matplotlib's pyplot
is not thread-safe). bench/RESULTS.md, "A ROS run starts at once".
"""
from __future__ import annotations

import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tank_control.harness.scenario_file import Scenario

#: the file analysis.png is written to ahead, replaced onto analysis.png when it is used
PART = '.analysis-ahead.png'


class AnalysisAhead:
    """The imports of the results' writers at once, then (after :meth:`start`) the loop
    analysis of ``scenario`` for the controller's starting parameters, in a daemon thread."""

    def __init__(self, scenario: Scenario, out: Path, title: str, draw: bool = True) -> None:
        self.scenario = scenario
        self.draw = draw                   # False: the reports only, no analysis.png
        self.part = out / PART
        self.title = title
        self.params: dict[str, Any] | None = None
        self.cases: list[Any] | None = None
        self._go = threading.Event()
        self._thread = threading.Thread(target=self._work, name='analysis-ahead', daemon=True)
        self._thread.start()

    def start(self, params: Mapping[str, Any]) -> None:
        """Analyse the loop for ``params`` (the controller's parameters now; {} : nothing)."""
        self.params = dict(params)
        self._go.set()

    def _work(self) -> None:
        import tank_control.harness.analysis  # noqa: F401 - the imports first, whatever comes
        if self.draw:
            import tank_control.harness.plotting  # noqa: F401
        self._go.wait()
        if not self.params:
            return
        try:
            from tank_control.core.scenario_loops import loop_cases
            from tank_control.harness.analysis import plot_analysis
            cases = loop_cases(self.scenario.sections, self.params)
            for case in cases:
                case.report()                                   # cached on the case
            if cases and self.draw:
                plot_analysis(cases, self.part, title=self.title)
            self.cases = cases
        except Exception:           # noqa: BLE001 - computed again at the end, which reports it
            self.cases = None

    def take(self, params: Mapping[str, Any]) -> list[Any] | None:
        """The loop cases (reports computed) if ``params`` are the ones analysed, else None
        (and the file written ahead removed)."""
        self._go.set()
        self._thread.join()
        if self.cases is not None and self.params == dict(params):
            return self.cases
        self.part.unlink(missing_ok=True)
        return None

    def place(self, path: Path) -> Path | None:
        """``analysis.png`` written ahead moved to ``path``, or None when there is none."""
        if not self.part.exists():
            return None
        self.part.replace(path)
        return path
