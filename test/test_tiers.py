"""The test tiers of ``test/conftest.py``: each test gets exactly one, and the unit tier stays
pure. Each case runs pytest in-process on a small tree laid out like ours (``setup.cfg`` and
``test/conftest.py`` copied verbatim).
"""

from __future__ import annotations

from pathlib import Path
import shutil
import textwrap

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def tree(pytester: pytest.Pytester) -> pytest.Pytester:
    shutil.copy(ROOT / 'setup.cfg', pytester.path / 'setup.cfg')
    (pytester.path / 'test' / 'e2e').mkdir(parents=True)
    shutil.copy(ROOT / 'test' / 'conftest.py', pytester.path / 'test' / 'conftest.py')
    return pytester


def write(tree: pytest.Pytester, path: str, source: str) -> None:
    (tree.path / path).write_text('import pytest\n' + textwrap.dedent(source))


def selected(tree: pytest.Pytester, tier: str) -> set[str]:
    result = tree.runpytest_inprocess('--collect-only', '-q', '-m', tier)
    return {line.split('::')[-1] for line in result.outlines if '::' in line}


def test_tier_is_derived_from_folder_and_fixtures(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        def test_pure(): pass
        def test_with_context(context): pass
        def test_with_executor(executor): pass
    """)
    write(tree, 'test/e2e/test_b.py', """
        def test_in_e2e_folder(): pass
    """)
    assert selected(tree, 'unit') == {'test_pure'}
    assert selected(tree, 'node') == {'test_with_context', 'test_with_executor'}
    assert selected(tree, 'e2e') == {'test_in_e2e_folder'}


def test_explicit_marker_wins(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        pytestmark = pytest.mark.e2e
        def test_runs_a_process(): pass
    """)
    write(tree, 'test/test_c.py', """
        @pytest.mark.node
        def test_marked_node(): pass
    """)
    assert selected(tree, 'e2e') == {'test_runs_a_process'}
    assert selected(tree, 'node') == {'test_marked_node'}
    assert selected(tree, 'unit') == set()


def test_two_tiers_fail_collection(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        pytestmark = pytest.mark.e2e
        @pytest.mark.unit
        def test_both(): pass
    """)
    result = tree.runpytest_inprocess()
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(['*test_a.py::test_both: two tiers (e2e, unit)*'])


def test_unit_marker_with_an_rclpy_context_fails_collection(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        @pytest.mark.unit
        def test_claims_unit(context): pass
    """)
    result = tree.runpytest_inprocess()
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*test_claims_unit: marked unit but uses the 'context'*"])


def test_unknown_tier_name_fails(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        @pytest.mark.unti
        def test_typo(): pass
    """)
    result = tree.runpytest_inprocess()
    assert result.ret == pytest.ExitCode.INTERRUPTED  # --strict-markers: collection error
    result.stdout.fnmatch_lines(["*'unti' not found in `markers`*"])


def test_unit_test_starting_a_process_fails(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        import subprocess, sys
        def test_spawns(): subprocess.run([sys.executable, '-c', 'pass'])
    """)
    result = tree.runpytest_inprocess()
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(['*TierError: a unit test started a process*'])


def test_unit_test_initializing_rclpy_fails(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        def test_inits():
            import rclpy
            from rclpy.context import Context
            rclpy.init(context=Context())
    """)
    result = tree.runpytest_inprocess()
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(['*TierError: a unit test initialized an rclpy context*'])


def test_sim_is_marked_and_leaves_the_unit_tier(tree: pytest.Pytester) -> None:
    """A closed loop of seconds is marked sim: out of the edit-test loop, pure all the same."""
    write(tree, 'test/test_a.py', """
        @pytest.mark.sim
        def test_closed_loop(): pass
        def test_pure(): pass
    """)
    assert selected(tree, 'sim') == {'test_closed_loop'}
    assert selected(tree, 'unit') == {'test_pure'}


def test_sim_marker_with_an_rclpy_context_fails_collection(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        @pytest.mark.sim
        def test_claims_sim(executor): pass
    """)
    result = tree.runpytest_inprocess()
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*test_claims_sim: marked sim but uses the 'context'*"])


@pytest.mark.node  # not unit: this test's own guard would refuse the inner test's process
def test_sim_test_starting_a_process_fails(tree: pytest.Pytester) -> None:
    write(tree, 'test/test_a.py', """
        import subprocess, sys
        @pytest.mark.sim
        def test_spawns(): subprocess.run([sys.executable, '-c', 'pass'])
    """)
    result = tree.runpytest_inprocess()
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(['*TierError: a unit test started a process*'])
