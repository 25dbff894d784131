"""The baselines G-SLAM is compared with (the paper's Table 4): FastSLAM 1.0 and 2.0 on pole landmarks,
and a grid-map Rao-Blackwellised particle filter. They share the filter's interface (`gslam.filter.SlamFilter`)."""
