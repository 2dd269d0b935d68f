"""scapy twin of the plant message, for crafting and dissecting single packets."""
from __future__ import annotations

from scapy.fields import IntField, ShortField
from scapy.layers.inet import UDP
from scapy.packet import Packet, bind_layers

from civic.wire import DEFAULT_UDP_PORT


class PlantMessage(Packet):
    """The 20-byte plant control message (docs/wire-format.md)."""

    name = "PlantMessage"
    fields_desc = [
        IntField("seq", 0),
        ShortField("l1", 0), ShortField("l2", 0), ShortField("l3", 0), ShortField("l4", 0),
        ShortField("p1", 0), ShortField("v1", 0), ShortField("v2", 0),
        ShortField("verdict", 0),
    ]


bind_layers(UDP, PlantMessage, dport=DEFAULT_UDP_PORT)
