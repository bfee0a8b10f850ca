"""Jobs: each command's work as a library call (open the input, build the :class:`~prc_slam.Pipeline`,
attach file and viewer sinks, write the outputs). This layer sits above the core, ``data_tools``
and ``prc_slam.viz``; the CLI (``prc_slam.cli``) only parses options and calls it."""
