"""Live runs: a sensor on the wire (Velodyne or Ouster UDP packets, or a recording paced at its
recorded rate) through the offline pipeline, sweep by sweep, with latency and drops measured."""
