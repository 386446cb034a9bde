"""The baseline memories of the seven-condition evaluation, built from the same bank as MEMORA:
Flat-1D (chronological text records) and Graph-2D (an entity-relation graph), each raw or
processed depending on the bank they are built from."""

from memora_graph.baselines.flat1d import Flat1DMemory
from memora_graph.baselines.graph2d import Graph2DMemory

__all__ = ["Flat1DMemory", "Graph2DMemory"]
