"""Networks: DeepVO (:mod:`~lossvo.models.deepvo`) and FlowNetS weight loading
(:mod:`~lossvo.models.flownet`)."""

from lossvo.models.deepvo import DeepVO, LSTMState
from lossvo.models.flownet import LoadReport, load_flownet

__all__ = ["DeepVO", "LSTMState", "LoadReport", "load_flownet"]
