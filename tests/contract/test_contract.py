"""Every contract case as one pytest item (`make qa`; `make test` leaves this folder out).

    .venv/bin/python -m pytest tests/contract [-k WORDS]

Each case is judged in a fresh interpreter, as `python -m tests.contract.run` does; the
per-category table ("tried N  held M") is printed at the end of the session.
"""

from __future__ import annotations

import pytest

from tests.contract.run import case_id, load_cases, verdict

CASES = load_cases()


@pytest.mark.parametrize("case", CASES, ids=[case_id(c) for c in CASES])
def test_contract_case(case, contract_verdicts):  # type: ignore[no-untyped-def]
    result = verdict(case)
    contract_verdicts[case_id(case)] = result
    assert result["why"] is None, (
        f"{result['why']} ({result.get('seconds')} s, {result.get('rss_mb')} MB)"
    )
