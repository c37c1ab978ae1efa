"""Every shipped scenario is listed in docs/scenarios.md (by name), where a reader looks for
what it shows, the document's claim and our number."""
from __future__ import annotations

import re

from support import SCENARIOS

DOCS = SCENARIOS.parents[1] / 'docs' / 'scenarios.md'


def test_every_shipped_scenario_is_in_docs_scenarios_md():
    text = DOCS.read_text()
    missing = [p.stem for p in sorted(SCENARIOS.glob('*.yaml'))
               if not re.search(rf'\b{re.escape(p.stem)}\b', text)]
    assert not missing, f'not in docs/scenarios.md: {missing}'
