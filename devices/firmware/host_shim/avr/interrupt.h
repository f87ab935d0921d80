#ifndef HOST_SHIM_AVR_INTERRUPT_H
#define HOST_SHIM_AVR_INTERRUPT_H
#define ISR(vector, ...) void vector(void)
#define ISR_ALIASOF(v) 0
#define sei()
#define cli()
#endif
