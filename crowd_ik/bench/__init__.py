"""The benchmark: workloads, the compiled peers and the chart behind `crowd-ik bench`."""
