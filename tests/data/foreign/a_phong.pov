#version 3.7;
global_settings { assumed_gamma 1.0 ambient_light rgb <0.2, 0.2, 0.2> max_trace_level 5 }
camera { perspective location <0, 1.2, -4> look_at <0, 0.6, -0> sky <0, 1, -0> right x * 1 up y angle 40 }
background { rgb <0, 0, 0> }
light_source { <3, 4, -3> color rgb <1, 1, 1>  }
sphere { <0, 1, -0>, 1 pigment { rgb <0.7, 0.2, 0.1> } finish { ambient rgb <0.142857143, 0.25, 0.2> diffuse 1 phong 0.5 phong_size 24 reflection { 0 }  } }
plane { <0, 1, -0>, 0 pigment { rgb <0.8, 0.6, 0.3> } finish { ambient rgb <0.125, 0.166666667, 0.333333333> diffuse 1 phong 0 phong_size 1 reflection { 0 }  } }
