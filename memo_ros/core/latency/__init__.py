"""The live graph's latency policy: which frames every node sheds under load, and when."""
