"""The dashboard tests' shared browser (support/browser.py ``chromium_page``) is closed when
the session ends, and nothing of it (chromedriver, chromium) is left running."""
from __future__ import annotations

from collections.abc import Iterator

import pytest
from support.browser import close_shared_chromium


@pytest.fixture(scope='session', autouse=True)
def _shared_chromium_closed() -> Iterator[None]:
    yield
    assert close_shared_chromium() == [], 'chromedriver or chromium left running'

