"""Neural posterior estimation in JAX: spline flows, flow matching (FMPE), NPE and APT / SNPE-C."""

from ._apt import Execution as Execution, RoundSchedule as RoundSchedule, apt as apt
from ._apt_state import APTState as APTState, load_state as load_state, save_state as save_state
from ._config import (
    FlowMatchingSettings as FlowMatchingSettings,
    NPEConfig as NPEConfig,
    SplineFlowSettings as SplineFlowSettings,
    TrainingSettings as TrainingSettings,
    as_record as as_record,
)
from ._embeddings import IdentityEmbedding as IdentityEmbedding, MLPEmbedding as MLPEmbedding
from ._npe import npe as npe
from ._observation import (
    OBSERVATIONS as OBSERVATIONS,
    AbstractObservation as AbstractObservation,
    StatisticsMLP as StatisticsMLP,
    TrajectoryCNN as TrajectoryCNN,
)
from ._posterior import Posterior as Posterior
from ._prior import BoxPrior as BoxPrior
from ._standardize import ChannelStandardization as ChannelStandardization
from ._vehicle import IdentifySettings as IdentifySettings, identify as identify
from ._windowed import identify_problem as identify_problem, input_channels as input_channels
