"""Citations a reader can look up (issue 33 §4): every citation key used in the package, its
scenario files and its docs is defined in docs/references.md, the old document numbers
("000 eq. 19", "004 §3.6") are gone, and nothing points outside the repository (the source
documents and their digests are not shipped)."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
REFERENCES = ROOT / 'docs' / 'references.md'
#: A citation: ``[Key]``, a capitalised key of 5+ letters (not all capitals) and an optional
#: year, not a subscript (``list[Event]``, ``Callable[[Progress], None]``) nor a Markdown link.
CITATION = re.compile(r'(?<![\w\]\[])\[([A-Z][a-z][A-Za-z]{3,}(?:\d{4})?)\](?!\()')
#: The labels used before docs/references.md: a document number and a place in it.
OLD_LABEL = re.compile(r'(?<![\w.\-/\[])00[0-4](?:\'s)? (?:eqs?\.|§|Table|Figs?\.?|\(|—)')
#: A path or a section of an internal document a user's clone does not have (``SPEC §3``).
OUTSIDE = re.compile(r'\.\./shared|SPEC\.md|\bSPEC ?§|SPEC-supplement|seeds/')


def _files() -> list[Path]:
    found = [ROOT / 'README.md']
    found += sorted((ROOT / 'docs').glob('*.md'))
    found += sorted((ROOT / 'tank_control').rglob('*.py'))
    found += sorted((ROOT / 'config').rglob('*.yaml'))
    return found


def _defined() -> set[str]:
    text = REFERENCES.read_text()
    return set(re.findall(r'^#+ \[([A-Za-z0-9]+)\]', text, re.M)) | set(
        re.findall(r'\*\*\[([A-Za-z0-9]+)\]\*\*', text))


def test_every_citation_key_resolves_in_references_md():
    defined = _defined()
    assert {'Viteckova', 'DeadTimeNotes', 'Ikonen', 'Michalski2021', 'Precup2013', 'Checks',
            'ZieglerNichols1942', 'Skogestad2003', 'AstromHagglund2004'} <= defined
    used: dict[str, list[str]] = {}
    for path in _files():
        for number, line in enumerate(path.read_text().splitlines(), 1):
            for key in CITATION.findall(line):
                used.setdefault(key, []).append(f'{path.relative_to(ROOT)}:{number}')
    assert len(used) >= 8, sorted(used)
    missing = {key: places[:3] for key, places in used.items() if key not in defined}
    assert not missing, f'keys not defined in docs/references.md: {missing}'


def test_no_old_document_numbers_and_no_path_outside_the_repository():
    """Checked in every file, the node adapters included (they use no labels today)."""
    old, outside = [], []
    for path in _files():
        for number, line in enumerate(path.read_text().splitlines(), 1):
            where = f'{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}'
            if OLD_LABEL.search(line):
                old.append(where)
            if OUTSIDE.search(line):
                outside.append(where)
    assert not old, 'document numbers instead of citation keys:\n' + '\n'.join(old[:20])
    assert not outside, 'paths outside the repository:\n' + '\n'.join(outside[:20])


def test_an_internal_section_label_is_caught():
    """The pattern itself: ``SPEC §3`` (a section of a document outside the repository) is
    caught, a command line's ``NODE.PARAM=SPEC`` is not."""
    assert OUTSIDE.search('exact dead time (SPEC §3; [Ikonen])')
    assert OUTSIDE.search('see SPEC§2')
    assert not OUTSIDE.search('--grid NODE.PARAM=SPEC ...')
    assert not OUTSIDE.search('exact dead time ([Checks] §2; [Ikonen])')
