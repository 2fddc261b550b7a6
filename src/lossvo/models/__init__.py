"""Networks: DeepVO (:mod:`~lossvo.models.deepvo`), FlowVO (:mod:`~lossvo.models.flowvo`) and FlowNetS
weight loading (:mod:`~lossvo.models.flownet`).

A network names the batch entries it reads in ``INPUTS`` (DeepVO: frames; FlowVO: flow and K), and
:func:`apply` hands it those of a batch (:mod:`lossvo.data.datamodules`)."""

from collections.abc import Mapping

from torch import Tensor, nn

from lossvo.models.deepvo import DeepVO, LSTMState
from lossvo.models.flownet import LoadReport, load_flownet
from lossvo.models.flowvo import FlowVO


def inputs_of(model: nn.Module) -> tuple[str, ...]:
    """The batch entries a network reads: its ``INPUTS``, or frames alone."""
    return tuple(getattr(model, "INPUTS", ("frames",)))


def apply(model: nn.Module, batch: Mapping[str, Tensor]) -> Tensor:
    """A network's outputs (B, L-1, dim) for a batch of windows, of which it reads :func:`inputs_of`."""
    return model(**{name: batch[name] for name in inputs_of(model)})


__all__ = ["DeepVO", "FlowVO", "LSTMState", "LoadReport", "apply", "inputs_of", "load_flownet"]
