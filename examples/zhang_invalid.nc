%
(Zhang's example NURBS as G06.2, as printed in the paper: NOT a valid curve.)
(Order P3 makes its 9 knots the right count for 6 points; still rejected for)
(the zero weights R0 and the decreasing knots K0.7 and K0.6. R1 on the last)
(point: the paper gives only 5 weights for 6 points.)
N10 G21 G90 G17
N20 G06.2 P3 K1.6 X0 Y0 Z0 R0 F18000
N30 K1.7 X1 Y1 Z2 R0
N40 K0.7 X2 Y1 Z2 R0.405
N50 K1.25 X3 Y1.5 Z2 R0.0636
N60 K0.6 X3 Y2 Z2.5 R0.742
N70 K0.85 X3.5 Y3 Z3
N80 K1
N90 K1.2
N100 K1.2
N110 M30
%
