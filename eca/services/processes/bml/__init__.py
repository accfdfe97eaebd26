"""The BML realizer service: BML 1.0 blocks from the bus realized on the agents' faces and voices."""
