"""The board side: wire protocol, skin physics, simulated board, serial link."""
