"""The jobs that join the layers below: generation, evaluation, reproduction and its report.

`scenarios` produces episodes and `predictor` owns the dataset format and the model; neither may
import the other. Each job that needs both (and every job the command-line tools run) is one
library call here, shared by `tools/`, the demo, the reproduction, the benchmarks and the tests.
"""
