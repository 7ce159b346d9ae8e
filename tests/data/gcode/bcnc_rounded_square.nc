(Created by bCNC)
(Block-name: rounded square 60x50)
(Block-expand: 0)
(Block-enable: 1)
G21
G90
M3 S12000
g0 z3
g0 x20 y30
g1 z-1 f150
(incremental block: the outline relative to its start)
G91
G1Y30F700
G2X10Y10R10
G1X40
G2X10Y-10R10
G1Y-30
G2X-10Y-10R10
G1X-40
G2X-10Y10R10
(second pass, one more millimetre down)
G1Z-1F150
G1Y30F700
G2X10Y10R10
G1X40
G2X10Y-10R10
G1Y-30
G2X-10Y-10R10
G1X-40
G2X-10Y10R10
G90
g0 z3
M5
M2
