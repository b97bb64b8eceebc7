"""`memo-ros benchmark`: one module per suite and a shared report helper."""
