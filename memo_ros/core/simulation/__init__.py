"""The studio simulator: camera rigs, motions and the grey-value pictures rendered from them."""
