%
G21 G90
G0 X1 Y2
(comment)
G1 X3 F500
M2