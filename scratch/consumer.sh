CONS="imu.gyro_bias_sd_deg_per_h=1800 imu.accel_bias_sd_mg=50 imu.gyro_arw_deg_per_sqrt_h=0.84 imu.accel_vrw_mps_per_sqrt_s=0.0017 imu.gyro_bias_rw_deg_per_h_per_sqrt_h=30"
