"""Motion matching: per-frame features (root velocity, feet, future trajectory, foot contacts), a
database of clips and their mirror images, exact nearest-neighbour search batched over agents, and
a controller that turns a time-varying velocity / facing input into animation by periodic searches
and inertialized transitions (one ``lax.scan`` per agent, ``jax.vmap`` for a crowd).
"""

from ._features import (
    FeatureLayout as FeatureLayout,
    FeatureOptions as FeatureOptions,
    FeatureWeights as FeatureWeights,
    detect_feet as detect_feet,
    detect_hands as detect_hands,
)
from ._database import (
    MatchingDatabase as MatchingDatabase,
    build_database as build_database,
    normalize_features as normalize_features,
)
from ._search import SearchResult as SearchResult, search as search
from ._controller import (
    ControlInput as ControlInput,
    ControllerOptions as ControllerOptions,
    MatchResult as MatchResult,
    check_input_speed as check_input_speed,
    control_input as control_input,
    motion_matching as motion_matching,
)
