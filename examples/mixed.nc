%
(mixed.nc: rapids, lines, arcs in G17/G18/G19 with I J K and R, a cubic G06.2 NURBS)
(every XYZ within +/-150 mm; feeds in mm/min)
N10 G21 G90 G94 G17
N20 G00 X0 Y0 Z10                  (rapid above the start)
N30 G01 Z0 F1500                   (plunge: non-tangent corner to the next line)
N40 X40 F3000                      (line along +X)
N50 G03 X60 Y20 I0 J20             (CCW quarter, I J: tangent to the line)
N60 G01 Y60                        (tangent line)
N70 G02 X80 Y80 R20                (CW quarter, R: tangent)
N80 G01 X100                       (tangent line)
N90 G03 X100 Y120 R-25             (arc > 180 deg, negative R: non-tangent corner)
N100 G18 G02 X120 Z0 I10 K0        (ZX plane half circle, dips to Z-10)
N110 G19 G03 Y100 Z0 J-10 K0       (YZ plane half circle, rises to Z+10)
N120 G17 G02 X120 Y100 I-10 J0     (full circle, end = start)
N130 G06.2 P4 K0 X120 Y100 Z0 F2400 (cubic NURBS; first point = current position)
N140 K0 X110 Y80 Z5
N150 K0 X90 Y90 Z10 R2
N160 K0 X70 Y60 Z5
N170 K0.4 X50 Y40 Z0
N180 K0.7 X30 Y30
N190 K1
N200 K1
N210 K1
N220 K1
N230 G01 X0 Y0 F3000               (G01 ends G06.2 mode)
N240 G00 Z10
N250 M30
%
