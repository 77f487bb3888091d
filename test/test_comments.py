"""Comments say why: no issue numbers anywhere in the Python sources, no measured figures in
the package's comments and docstrings.

An issue number says nothing to a reader of the code, and the history of a line belongs in
its commit message. A measured cost (microseconds, a share of a core, a speed-up) is true of
one machine on one day: it goes to ``docs/benchmarks.md``, where it can be measured again,
and the comment keeps the reason. Specifications are not measurements and stay: a data
sheet's 500 us wake-up, a 1500 us neutral pulse, a 0.25 s timeout, a bus transfer's 3.3 ms.

The figure rule looks for what a measurement reads like, not for every number with a unit:
a time or size next to CPU, ``measured``, ``instead of``, ``per message`` and the like, a
share of a core, a cost stated as a figure, a speed-up by a number. The tests below pin both
sides: lines that were in the code before they moved are caught, specifications of the code
are not.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Iterator
import io
from pathlib import Path
import re
import tokenize

import pytest

from support.sources import PACKAGES, python_files, ROOT, TESTS

pytestmark = pytest.mark.unit

#: The word "issue" (or "issues") and a number, with or without "#" between them.
ISSUE = re.compile(r'\bissues?\s*(?:#\s*)?\d', re.IGNORECASE)

_NUMBER = r'\d[\d.,]*(?:\s?-\s?\d[\d.,]*)?'     # 3, 0.4, 1,5, 10-23
_TIME = rf'{_NUMBER}\s?(?:us|µs|ms)\b'
_FIGURE = rf'{_NUMBER}\s?(?:us|µs|ms|%|MB|kB|KiB|MiB)(?!\w)'
#: Words that make a time, size or share on the same line a comparison of measured costs.
_COMPARED = (r'instead of|\bagainst\b|\bfaster\b|\bslower\b|\bdearer\b|\bcheaper\b|\btook\b'
             r'|reference machine|\bresident\b|\bRSS\b'
             r'|\bper (?:message|call|sample|cycle|dispatch|check|step|wake-up)\b')
_WORD_NUMBER = r'two|three|four|five|six|seven|eight|nine|ten|twenty|fifty|a hundred'
MEASURED = [
    # a figure compared or put per message: '0.4 instead of 3.2 us', '29 us ... per message'
    re.compile(rf'(?=.*(?:{_FIGURE}))(?=.*(?:{_COMPARED}))', re.IGNORECASE),
    # CPU time: '0.4 ms of CPU', '29 us of writer CPU', 'half a millisecond of CPU'
    re.compile(rf'(?:{_FIGURE}|(?:milli|micro)seconds?)\s+of\s+(?:\w+\s+)?CPU\b',
               re.IGNORECASE),
    # a share of a core: '1.3 % of a core'
    re.compile(rf'{_NUMBER}\s?(?:%|percent) of (?:a|one|the)\s+(?:\w+\s+)?core\b', re.IGNORECASE),
    # 'measured 3.1 us', 'measured: 70 -> 113 MB', 'which measured 29 us'
    re.compile(r'\bmeasured:?\s+(?:about\s+|~\s?)?\d', re.IGNORECASE),
    # a cost or an estimate as a time: 'costs ~80 us', '(about 5 us)'
    re.compile(rf'\bcosts?\s+(?:about\s+|~\s?|only\s+)?{_TIME}'
               rf'|(?:\babout\s+|~\s?){_TIME}', re.IGNORECASE),
    # measured here: '6.7 us here', 'about 0.1 s here'
    re.compile(rf'{_NUMBER}\s?(?:s|us|µs|ms)\s+here\b', re.IGNORECASE),
    # a speed-up by a number: '10x faster', "20x numpy's", 'ten times more'
    re.compile(rf'\b\d[\d.]*\s?x\s+(?:faster|slower|more|less|dearer|cheaper)\b'
               rf"|\b\d[\d.]*x\s+\w+'s\b"
               rf'|\b(?:\d[\d.]*|{_WORD_NUMBER})\s+times\s+(?:faster|slower|more|less|dearer'
               rf'|cheaper)\b', re.IGNORECASE),
]


def issue_references(text: str) -> Iterator[tuple[int, str]]:
    """Every line of ``text`` (code, comment, docstring or string) naming an issue number."""
    for number, line in enumerate(text.splitlines(), 1):
        if ISSUE.search(line):
            yield number, line.strip()


def comment_lines(source: str) -> Iterator[tuple[int, str]]:
    """The comment lines and string statements (docstrings) of a Python source, numbered."""
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) \
                and isinstance(node.value.value, str):
            for offset, line in enumerate(node.value.value.splitlines()):
                yield node.lineno + offset, line


def measured_figures(source: str) -> Iterator[tuple[int, str]]:
    """The comment and docstring lines of ``source`` that read like a measured cost."""
    for number, line in comment_lines(source):
        if any(p.search(line) for p in MEASURED):
            yield number, line.strip()


def scan(paths: list[Path], rule: Callable[[str], Iterator[tuple[int, str]]]) -> str:
    """What ``rule`` finds in each of ``paths``, one ``path:line: text`` per hit."""
    return '\n'.join(f'{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{n}: '
                     f'{line}' for path in paths
                     for n, line in rule(path.read_text(encoding='utf-8')))


# -- the tree ---------------------------------------------------------------------------------

def test_no_python_file_names_an_issue_number() -> None:
    found = scan(python_files(*PACKAGES, TESTS, 'scripts'), issue_references)
    assert not found, ('issue numbers in the sources (history goes to the commit message; say '
                       'what failed and why instead):\n' + found)


def test_no_comment_of_the_package_or_its_scripts_carries_a_measured_figure() -> None:
    found = scan(python_files(*PACKAGES, 'scripts'), measured_figures)
    assert not found, ('measured figures in comments (move them to docs/benchmarks.md, keep '
                       'the reason in the comment):\n' + found)


# -- the rules themselves ---------------------------------------------------------------------

ISSUE_WORD = 'iss' + 'ue'  # built, so that this file does not name an issue itself


@pytest.mark.parametrize('line', [
    f'# {ISSUE_WORD} 8',
    f'# -- the time policy ({ISSUE_WORD} 8) ---',
    f'    """{ISSUE_WORD.capitalize()} 8: a command stamped 20 s ahead was mapped to duties."""',
    f"x = 'see {ISSUE_WORD} #12'",
    f'# {ISSUE_WORD}s 8 and 9',
])
def test_an_issue_number_is_found_in_any_form(line: str) -> None:
    assert list(issue_references(f'a = 1\n{line}\n')) == [(2, line.strip())]


@pytest.mark.parametrize('line', [
    "# the stream's issues are counted per second",
    '# Issue the RESET command, then wait 2 ms',
])
def test_the_word_issue_alone_is_not_an_issue_number(line: str) -> None:
    assert not list(issue_references(line))


#: Lines that were in the package before their figures moved to docs/benchmarks.md (one
#: reintroduced by hand as well), each of which the rule must catch.
MEASURED_LINES = [
    '# measured 3.1 us here',
    '# Model steps integrated in one late tick before time is skipped. A step costs ~80 us, far',
    '#: 3-vector: 0.4 instead of 3.2 us for ``np.all(np.isfinite(a))`` here); larger arrays.',
    "#: libyaml's emitter when PyYAML has it (10x faster: the file is rewritten at every flush).",
    '        # skew(omega) @ v is omega x v; np.cross costs ten times more on 3-vectors.',
    "ok = math.isfinite(f)  # a float: math's test, 20x numpy's",
    '        # (the same CLOCK_REALTIME value, 0.06 us instead of the 2-6 us of clock.now()); the',
    '        # 29 us of writer CPU per message in bringup enbarr_sim --record; draining every',
    "# timers took 1.1 of the process's 1.3 % of a core, their callbacks' own work 0.4 %). So",
    '# executor wake-up costs about half a millisecond of CPU in rclpy whatever the callback',
    '# 0.4 ms of CPU each on the reference machine), so a five-hop IMU -> thruster chain',
    '# check (about 5 us), never a graph query (about 220 us each).',
    '# memory (measured: 70 -> 113 MB over numpy, rclpy and ``scipy.linalg``) and a few',
    '# Scanning every installed distribution takes about 0.1 s here, and bringup resolves',
]


@pytest.mark.parametrize('line', MEASURED_LINES)
def test_a_measured_figure_in_a_comment_is_found(line: str) -> None:
    assert [n for n, _ in measured_figures(f'a = 1\n{line.strip()}\n')] == [2]


def test_a_measured_figure_in_a_docstring_is_found() -> None:
    source = 'def f():\n    """Say why.\n\n    It costs 17 us per call here.\n    """\n'
    assert [n for n, _ in measured_figures(source)] == [4]


#: Specifications of the code and its devices, in the package today: not measurements.
SPECIFICATION_LINES = [
    '# nothing ran before the sleep (a first configuration), 500 us after waking.',
    '#  1500 us for about a second before driving, and a new arming after the signal stopped',
    '#  4.9 us at 50 Hz (1.3 % of the 1100-1900 us range, enough to bias small commands, which',
    '# produces thrust; Blue Robotics Basic ESC: 1100-1900 us, stopped 1500 us, +-25 us) and',
    '# 20 ms adapter timeout: a 33-byte block takes 3.3 ms at 100 kHz; a stalled bus then costs',
    '# at most 2 x 20 ms per transfer (one retry).',
    '#: Waits the protocol document asks for after STOP and RESET [s] (1 ms, 2 ms); longer here,',
    '# long as two gpiozero writes, tens of microseconds, well above the 1-2 us minimum of the',
    '# a scan, 1 deg resolution), sample duration 0.5 ms (2000 samples/s; up to 8000 in the',
    "# degraded when it refuses more than 5 % of a second's commands.",
    '#: How long a Python thread may hold the GIL while another waits [s] (CPython default 5 ms).',
    '# executor thread for a whole default interval: that alone would break the 2 ms latency',
    '# duties travel in 0.01 %',
    '# servos between 4.3 % and 9.4 %, manual Table 1.1). Both tables are measured per thruster',
    '# The state is 9 Python floats: on 3-vectors, scalar arithmetic is several times faster',
    '# MAX_FILE_BYTES = 256 << 10      # a profile file [bytes] (the largest shipped: 5 KB)',
    "# the tmpfs of the disk fault (over the recorder's 64 MB margin)",
    '# 13.8 drops 0.1 % of the samples of a vehicle at rest.',
    '#   ``pi4_core_fraction_estimate`` = that x 6 (a Raspberry Pi 4 core runs CPython about six',
]


@pytest.mark.parametrize('line', SPECIFICATION_LINES)
def test_a_specification_is_not_a_measured_figure(line: str) -> None:
    assert not list(measured_figures(line + '\n'))


def test_a_reintroduced_figure_and_issue_are_reported_with_their_file(tmp_path: Path) -> None:
    """What the tree tests run, on a file with both reintroduced."""
    mod = tmp_path / 'mod.py'
    mod.write_text(f'"""A module."""\n\nX = 1  # measured 3.1 us here\n# {ISSUE_WORD} 8\n',
                   encoding='utf-8')
    clean = tmp_path / 'clean.py'
    clean.write_text('"""Wait 500 us for the oscillator (data sheet)."""\n', encoding='utf-8')
    assert scan([mod, clean], measured_figures) == f'{mod}:3: # measured 3.1 us here'
    assert scan([mod, clean], issue_references) == f'{mod}:4: # {ISSUE_WORD} 8'
