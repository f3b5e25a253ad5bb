"""Tools around the DEIF sensor network: launch runs (one host or several network-namespace
hosts), batches, figures and benchmarks. Every number is computed by the C++ executables
(the config by deif_config, the metrics by deif_sim --evaluate); this package launches,
reduces and plots."""
