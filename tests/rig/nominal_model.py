"""The nominal linear model (a second-order block at 1 kHz, unit static gain) that the diagnose tests give
`rig diagnose --model`, as plant TOML."""

NOMINAL_TOML = """name = "nominal"
sample_period_s = 0.001
[encoder]
bits = 12
[noise]
kind = "uniform"
bound_rad = 0.0002
[[blocks]]
type = "linear"
a = [-1.73691838, 0.76805512]
b = [0.0, 0.01625312, 0.01488362]
"""
