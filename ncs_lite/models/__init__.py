"""dSLATE's parts, a file per concept: dVAE, slot attention, SLATE decoder, dynamics."""
from .decoder import TransformerDecoder
from .dslate import MODEL_VERSION, DSlate, SlotInference
from .dvae import DVAE, cosine_anneal, tau_schedule
from .dynamics import Dynamics
from .slot_attention import SlotAttention

__all__ = ["DVAE", "DSlate", "Dynamics", "MODEL_VERSION", "SlotAttention", "SlotInference",
           "TransformerDecoder", "cosine_anneal", "tau_schedule"]
