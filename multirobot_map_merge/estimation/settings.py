"""Settings of the estimation: one object feeding validation, the offline tool and the node.

Each stage declares its own settings next to its code; EstimationSettings is all of them in one flat object (a
stage reads `settings.ratio`, the CLI and the node build one object), plus what concerns the whole run.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .features import FeatureSettings
from .hypotheses import HypothesisSettings
from .refine import RefineSettings
from .search import SearchSettings
from .validation import must_be_positive
from .verify import AcceptanceSettings

STAGES = (FeatureSettings, HypothesisSettings, RefineSettings, AcceptanceSettings, SearchSettings)


@dataclass
class EstimationSettings(SearchSettings, AcceptanceSettings, RefineSettings, HypothesisSettings, FeatureSettings):
    # the fields of the stages come first, in the order of STAGES (dataclasses collect them from the last base)
    threads: int = 2                  # pairs matched in parallel
    # the batches of matches run on `threads` worker processes (workers.py), else on threads (which the GIL holds
    # back: a second thread adds 0.14 of a core's work, a second process a whole core's)
    processes: bool = True
    # a member that the maps left out single out leaves the merge (eviction.py): for one estimation of final maps
    # (merge_maps, the node's estimate afresh: for_final_maps); the node's others turn it off (see ros/params.py)
    evict: bool = True
    # the placements of an estimation afresh refined together at its end (relax.py, relax.FINAL): for one
    # estimation of final maps (merge_maps); in the node tracking refines the kept placements together instead, and
    # a group that outgrew the tracked one is refined with tracking's limits (estimator.relax_group)
    relax_final: bool = True
    # the grids left out of an estimation afresh searched once more onto the merge (growth.search_left_out): for one
    # estimation of final maps; in the node's other estimations tracking checks every placement again in the next
    search_left_out: bool = True
    seed: int = 0

    def validate(self) -> None:
        """Raise ValueError naming the first bad setting."""
        for stage in STAGES:
            stage.validate(self)
        must_be_positive(self, 'threads')

    def replace(self, **changes) -> 'EstimationSettings':
        return dataclasses.replace(self, **changes)

    def for_final_maps(self) -> 'EstimationSettings':
        """These settings for the node's one estimate afresh of its static final maps: with the searches of the maps
        left out and eviction, as merge_maps. Not its final relaxation: the node's tracking relaxes the placements
        after, and with it the estimate afresh of 30 robots took the node's longest estimation past its 5 s bound
        (bench_node: 5.9 and 7.2 s)."""
        return self.replace(evict=True, search_left_out=True)
