"""Neural posterior estimation in JAX: spline flows, flow matching (FMPE), NPE and APT / SNPE-C."""

from ._apt import apt as apt
from ._apt_state import APTState as APTState, load_state as load_state, save_state as save_state
from ._build import build_flow as build_flow
from ._cnn import CNNEmbedding as CNNEmbedding
from ._config import (
    FlowMatchingSettings as FlowMatchingSettings,
    NPEConfig as NPEConfig,
    SequentialSettings as SequentialSettings,
    SplineFlowSettings as SplineFlowSettings,
    TrainingSettings as TrainingSettings,
    as_record as as_record,
)
from ._embeddings import (
    AbstractEmbedding as AbstractEmbedding,
    IdentityEmbedding as IdentityEmbedding,
    MLPEmbedding as MLPEmbedding,
    embedding_from_spec as embedding_from_spec,
    register_embedding as register_embedding,
)
from ._estimator import AbstractEstimator as AbstractEstimator
from ._flow import ConditionalFlow as ConditionalFlow, flow_from_spec as flow_from_spec
from ._flow_matching import (
    FlowMatchingEstimator as FlowMatchingEstimator,
    FlowMatchingLoss as FlowMatchingLoss,
    VectorField as VectorField,
    fmpe_from_spec as fmpe_from_spec,
)
from ._loss import (
    AbstractLoss as AbstractLoss,
    AtomicLoss as AtomicLoss,
    MaximumLikelihoodLoss as MaximumLikelihoodLoss,
    atom_indices as atom_indices,
    atomic_apt_loss as atomic_apt_loss,
    leak_penalty as leak_penalty,
)
from ._npe import npe as npe
from ._observation import (
    OBSERVATIONS as OBSERVATIONS,
    AbstractObservation as AbstractObservation,
    StatisticsMLP as StatisticsMLP,
    TrajectoryCNN as TrajectoryCNN,
)
from ._posterior import Posterior as Posterior
from ._prior import BoxPrior as BoxPrior
from ._sharding import (
    data_mesh as data_mesh,
    replicate as replicate,
    shard_batch as shard_batch,
    stack_batches as stack_batches,
)
from ._spline import (
    num_spline_params as num_spline_params,
    rq_spline_forward as rq_spline_forward,
    rq_spline_inverse as rq_spline_inverse,
)
from ._standardize import (
    AbstractStandardization as AbstractStandardization,
    ChannelStandardization as ChannelStandardization,
    GlobalStandardization as GlobalStandardization,
    NoStandardization as NoStandardization,
    Standardizer as Standardizer,
    TrajectoryStandardization as TrajectoryStandardization,
)
from ._summaries import DEFAULT_LAGS as DEFAULT_LAGS, summary_statistics as summary_statistics
from ._theta_map import (
    AbstractThetaMap as AbstractThetaMap,
    IdentityMap as IdentityMap,
    LogitMap as LogitMap,
)
from ._train import (
    eval_steps as eval_steps,
    fit as fit,
    init_opt_state as init_opt_state,
    make_optimizer as make_optimizer,
    train_step as train_step,
    train_steps as train_steps,
    trainable_filter as trainable_filter,
)
from ._vehicle import (
    IdentifySettings as IdentifySettings,
    identify as identify,
    seed_prior as seed_prior,
)
from ._windowed import identify_problem as identify_problem, input_channels as input_channels
