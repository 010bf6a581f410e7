%
G0 X1 0 Y1 0
G0 X20 (an unclosed comment Y90
G0 X30 / Y40
/G0 Y50
(only a comment
G0 X0 (a;b) Y0
G0 X- 0 . 5
%G0 X1
