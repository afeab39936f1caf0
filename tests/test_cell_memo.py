"""The worker memo of experiments.runner.cell: each kind of entry (observations, scoring
references, configurations, noise names) has its own bound, so one kind never evicts
another (before, all shared the observations' cap of 7)."""

from __future__ import annotations

from collections import OrderedDict

from experiments.runner import cell as cellmod
from experiments.runner.cell import MEMO_BOUNDS, CellContext, _memo_kind, _memoised


def _ctx() -> CellContext:
    return CellContext(spec_seed=0, masks=("full",), session_s=1.0, want_epochs=False,
                       memo=OrderedDict())


def test_each_kind_is_bounded_on_its_own() -> None:
    ctx = _ctx()
    calls: list[tuple] = []

    def put(kind: str, i: int) -> object:
        return _memoised(ctx, kind, (i,), lambda: calls.append((kind, i)) or (kind, i))

    put("config", 0)
    put("noise_name", 0)
    for i in range(3 * MEMO_BOUNDS["obs"]):
        put("obs", i)
        put("scoring", i)
    # the configuration and the noise name survive any number of observations
    assert put("config", 0) == ("config", 0) and put("noise_name", 0) == ("noise_name", 0)
    assert calls.count(("config", 0)) == 1 and calls.count(("noise_name", 0)) == 1
    for kind in ("obs", "scoring"):
        memo = _memo_kind(ctx, kind)
        assert len(memo) == MEMO_BOUNDS[kind]
        assert list(memo) == [(i,) for i in range(3 * MEMO_BOUNDS[kind] - MEMO_BOUNDS[kind],
                                                    3 * MEMO_BOUNDS[kind])]
    n = len(calls)
    put("obs", 3 * MEMO_BOUNDS["obs"] - 1)           # a hit: not recomputed
    assert len(calls) == n


def test_noise_names_do_not_evict_observations(monkeypatch) -> None:
    ctx = _ctx()
    _memoised(ctx, "obs", ("key",), lambda: "observations")
    monkeypatch.setattr(cellmod, "_noise_name", lambda c: f"name-{c.noise}")

    class FakeCell:
        def __init__(self, i: int) -> None:
            self.noise = f"n{i}"

        def file(self, _what: str) -> str:
            return f"/noise/{self.noise}.toml"

    for i in range(20):
        assert cellmod._memo_noise_name(FakeCell(i), ctx) == f"n{i}".replace("n", "name-n", 1)
    assert ("key",) in _memo_kind(ctx, "obs")
