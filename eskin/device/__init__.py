"""The board side: wire protocol v1 (:mod:`~eskin.device.protocol`, sans-I/O), the host's
state machine (:mod:`~eskin.device.host`) and serial link (:mod:`~eskin.device.link`),
the skin's physics (:mod:`~eskin.device.physics`), the simulated board
(:mod:`~eskin.device.board`, :mod:`~eskin.device.simulate`) and the firmware under
simavr (:mod:`~eskin.device.emulated`)."""
