"""Rows inference with a QUBO solver: each bundle is ``bundle_height`` rows (the paper's row
QUBO at 1; vertical edges inside a taller bundle, none between bundles), whole or cut into
segments of ``bundle_width`` pixels stitched where each pixel lies farthest from a cut."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from shared.bundles import Bundle
from shared.config import MatchConfig
from shared.energy import Costs
from shared.inference.qubo import QuboStrategy, TileProblem, encoded
from shared.level_inputs import LevelInputs


class QuboRows(QuboStrategy):
    """Each bundle's own costs encoded as they are (segments of the same rows share one cost
    computation)."""

    name = "qubo-rows"

    def problems(
        self, inputs: LevelInputs, config: MatchConfig, items: Sequence[Bundle]
    ) -> Iterator[TileProblem]:
        rows: tuple[int, int] | None = None
        row_costs: Costs | None = None
        for bundle in items:
            start, stop, first, last = bundle.as_list()
            if row_costs is None or rows != (start, stop):
                row_costs, rows = inputs.costs(config, start, stop), (start, stop)
            start_labels = self.warm_start(inputs, row_costs, bundle)
            yield encoded(inputs, config, bundle, row_costs.columns(first, last), start_labels)
