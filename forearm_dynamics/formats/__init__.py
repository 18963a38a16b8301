"""Text formats of other tools: OpenSim motion and storage tables (.mot/.sto)."""
