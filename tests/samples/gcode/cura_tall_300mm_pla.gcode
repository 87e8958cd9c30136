;FLAVOR:Marlin
;TIME:61234
;Filament used: 0.41237m
;Layer height: 0.2
;MINX:100
;MINY:100
;MINZ:0.2
;MAXX:120
;MAXY:120
;MAXZ:300
;TARGET_MACHINE.NAME:Creality CR-10 S5
;Generated with Cura_SteamEngine 5.6.0
M140 S60
M105
M190 S60
M104 S200
M105
M109 S200
M82 ;absolute extrusion mode
; Start G-code with the lines Moonraker's metadata parser reads
;Nozzle diameter = 0.4
;Filament type = PLA
;Filament name = Generic PLA
G92 E0 ; reset extruder
G28 ; home all axes
G1 Z2.0 F3000 ; move Z up a little to prevent scratching the bed
G1 X10.1 Y20 Z0.28 F5000.0 ; move to start position
G1 X10.1 Y100.0 Z0.28 F1500.0 E6 ; draw the first line
G1 X10.4 Y100.0 Z0.28 F5000.0 ; move to side a little
G1 X10.4 Y20 Z0.28 F1500.0 E12 ; draw the second line
G92 E0 ; reset extruder
G1 Z2.0 F3000 ; move Z up a little to prevent scratching the bed
G92 E0
G92 E0
G1 F2700 E-5
;LAYER_COUNT:1500
;LAYER:0
M107
G0 F6000 X100.0 Y100.0 Z0.2
;TYPE:WALL-OUTER
G1 F2700 E0
G1 F1200 X120 Y100 E0.66520
G1 X120 Y120 E1.33040
G1 X100 Y120 E1.99560
G1 X100 Y100 E2.66080
;TIME_ELAPSED:15308.5
;LAYER:1
M106 S255
G0 F6000 X100.0 Y100.0 Z0.4
;TYPE:WALL-OUTER
G1 F1500 X120 Y100 E3.32600
G1 X120 Y120 E3.99120
G1 X100 Y120 E4.65640
G1 X100 Y100 E5.32160
;TIME_ELAPSED:30617.0
;LAYER:2
G0 F6000 X100.0 Y100.0 Z0.6
;TYPE:WALL-OUTER
G1 F1500 X120 Y100 E5.98680
G1 X120 Y120 E6.65200
G1 X100 Y120 E7.31720
G1 X100 Y100 E7.98240
;TIME_ELAPSED:45925.5
; (layers 3 to 1499 trimmed from this test sample: only the header's ;MAXZ says how tall the part is)
G1 F2700 E2.98240
M140 S0
M107
G91 ;relative positioning
G1 E-2 F2700
G1 E-2 Z0.2 F2400 ;retract and raise Z
G1 X5 Y5 F3000 ;wipe out
G1 Z10 ;raise Z more
G90 ;absolute positioning
G1 X0 Y200 ;present print
M106 S0 ;turn off fan
M104 S0 ;turn off hotend
M140 S0 ;turn off bed
M84 X Y E ;disable all steppers but Z
M82 ;absolute extrusion mode
M104 S0
;End of Gcode
;SETTING_3 {"global_quality": "[general]\\nversion = 4\\nname = Standard Quality #2\\n
;SETTING_3 definition = creality_cr10_s5\\n\\n[metadata]\\ntype = quality_changes\\nqualit
;SETTING_3 y_type = standard\\nsetting_version = 22\\n\\n[values]\\nadhesion_type = skirt\\n\\n
;SETTING_3 ", "extruder_quality": ["[general]\\nversion = 4\\nname = Standard Quality #2\\ndef
;SETTING_3 inition = creality_cr10_s5\\n\\n[metadata]\\ntype = quality_changes\\nquality_ty
;SETTING_3 pe = standard\\nsetting_version = 22\\nposition = 0\\n\\n[values]\\ninfill_sparse_d
;SETTING_3 ensity = 15\\n\\n"]}
