#ifndef HOST_SHIM_AVR_INTERRUPT_H
#define HOST_SHIM_AVR_INTERRUPT_H
#define ISR(vector) void vector(void)
#define sei()
#define cli()
#endif
