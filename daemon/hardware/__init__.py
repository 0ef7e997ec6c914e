"""The display's hardware as the daemon sees it: the controllers as one fleet (serial, firmware
protocol), the Modbus lux sensor, and simulated stand-ins for both (real ptys, a real Modbus/TCP
server on 127.0.0.1)."""
