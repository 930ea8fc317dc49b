"""Pushing dynamics (Ch. 4): SQPD-Net, its baseline, pushing-tuple data, training, evaluation.

``config`` (hyper-parameters, presets), ``model`` (SQPD-Net, loss), ``baselines`` (4.7.1),
``data`` (on-disk tuple format), ``metrics``, ``train``, ``evaluate``.
"""

from .config import SQPDNetConfig, baseline_config, cpu_config, get_config, gpu_config
from .data import PushBatch, PushTensors, PushTuple, PushTupleWriter, load_split
from .model import SQPDNet, make_model, sqpd_loss

__all__ = [
    "PushBatch",
    "PushTensors",
    "PushTuple",
    "PushTupleWriter",
    "SQPDNet",
    "SQPDNetConfig",
    "baseline_config",
    "cpu_config",
    "get_config",
    "gpu_config",
    "load_split",
    "make_model",
    "sqpd_loss",
]
