G0 X0 Y00 C0
