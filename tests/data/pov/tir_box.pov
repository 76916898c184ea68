#version 3.7;
global_settings { assumed_gamma 1.0 ambient_light rgb <0.2, 0.2, 0.2> max_trace_level 10 adc_bailout 0.0 }
camera { perspective location <2.2, 2, -3.2> look_at <0, 0.5, -0> right x * 1.33333333 up y angle 39.3201208 }
background { rgb <0.3, 0.4, 0.6> }
light_source { <3, 6, -4> color rgb <0.8, 0.8, 0.8>  }
plane { <0, 1, -0>, 0 pigment { checker rgb <0.8, 0.8, 0.8>, rgb <0.1, 0.1, 0.1> translate <0,0.5,0> scale 0.5 } finish { ambient 0 diffuse 1 phong 0 phong_size 1 reflection { 0 } } }
box { <-0.5,-0.5,-0.5>, <0.5,0.5,0.5> rotate <0,-30,0> translate <0,0.51,0> pigment { rgbt <1,1,1,0.9> } finish { ambient 0 diffuse 0 reflection { 0 } } interior { ior 1.5 } }
